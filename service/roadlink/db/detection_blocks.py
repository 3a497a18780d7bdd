"""A batch's detections as one columnar block: what the `detection_block` table stores per batch.

A batch is written once and read whole or by time window, never row by row, so its detections
are kept together, column by column, in upload order (row r is entry r - 1): storing a batch is
one row, not one per detection with its batch's and deployment's ids repeated, and deleting it
is deleting that row. Readers decode only the columns they need.

The layout (version 1), little-endian:
- a header: `RLDB`, the version (1 byte), which optional features the block holds (1 byte:
  1 lane, 2 length, 4 vehicle class), the number of detections n (4 bytes), then the byte size
  of each of the four text columns (4 bytes each: sensor_id, detection_id, target,
  vehicle_class);
- position, velocity, timestamp: n float64 each;
- lane (n int16, `NO_LANE` where not reported) and length (n float64, NaN where not reported),
  each only when some detection of the batch reports it;
- the text columns, each a JSON array of strings and nulls (vehicle_class only when reported).

Numbers are stored as their bytes, so every value reads back exactly as it was validated.
"""

from __future__ import annotations

import struct
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import orjson

from roadlink.association.detections import (
    NO_LANE,
    Detections,
    FloatArray,
    IntArray,
    ObjectArray,
)

MAGIC = b"RLDB"
VERSION = 1
_HEADER = struct.Struct("<4sBBIIIII")
_LANE, _LENGTH, _CLASS = 1, 2, 4
NUMBER_COLUMNS = ("position", "velocity", "timestamp")
TEXT_COLUMNS = ("sensor_id", "detection_id", "target", "vehicle_class")


def encode(detections: Detections) -> bytes:
    """The block of `detections` (validated, in upload order)."""
    d = detections
    # The classes' list is made once, for the flag and the text (`d.features` compares the
    # object array to None element by element: several times as long); counted only when the
    # first reports none (a batch with classes most often has one in its first detection).
    classes = d.vehicle_class.tolist()
    reported = bool(classes) and (classes[0] is not None or classes.count(None) < len(classes))
    flags = (
        (_LANE if bool(d.has_lane.any()) else 0)
        | (_LENGTH if not bool(np.isnan(d.length).all()) else 0)
        | (_CLASS if reported else 0)
    )
    texts = [
        orjson.dumps(d.sensor_id.tolist()),
        orjson.dumps(d.detection_id.tolist()),
        orjson.dumps(d.target.tolist()),
        orjson.dumps(classes) if flags & _CLASS else b"",
    ]
    parts = [_HEADER.pack(MAGIC, VERSION, flags, len(d), *map(len, texts))]
    parts += [_float_bytes(d.position), _float_bytes(d.velocity), _float_bytes(d.timestamp)]
    if flags & _LANE:
        parts.append(np.asarray(d.lane, dtype="<i2").tobytes())
    if flags & _LENGTH:
        parts.append(_float_bytes(d.length))
    return b"".join(parts + texts)


def _float_bytes(values: FloatArray) -> bytes:
    return np.asarray(values, dtype="<f8").tobytes()


@dataclass(frozen=True)
class Block:
    """One stored block, decoded column by column on demand (see the module docstring)."""

    data: bytes
    n: int
    flags: int
    offsets: dict[str, tuple[int, int]]

    @classmethod
    def parse(cls, data: bytes) -> Block:
        """Read the header of a stored block; raises ValueError on anything else."""
        if len(data) < _HEADER.size:
            raise ValueError("not a detection block: too short")
        magic, version, flags, n, *text_sizes = _HEADER.unpack_from(data)
        if magic != MAGIC or version != VERSION:
            raise ValueError(f"not a version-{VERSION} detection block")
        offsets: dict[str, tuple[int, int]] = {}
        at = _HEADER.size
        sizes = [("position", 8 * n), ("velocity", 8 * n), ("timestamp", 8 * n)]
        if flags & _LANE:
            sizes.append(("lane", 2 * n))
        if flags & _LENGTH:
            sizes.append(("length", 8 * n))
        sizes += list(zip(TEXT_COLUMNS, text_sizes, strict=True))
        for name, size in sizes:
            offsets[name] = (at, size)
            at += size
        if at != len(data):
            raise ValueError("detection block of the wrong size")
        return cls(data, n, flags, offsets)

    def floats(self, name: str) -> FloatArray:
        """A number column (position, velocity, timestamp, length: NaN where not reported)."""
        if name == "length" and not self.flags & _LENGTH:
            return np.full(self.n, np.nan)
        at, _ = self.offsets[name]
        return np.frombuffer(self.data, dtype="<f8", count=self.n, offset=at).astype(np.float64)

    def lanes(self) -> IntArray:
        """The lane column (`NO_LANE` where not reported)."""
        if not self.flags & _LANE:
            return np.full(self.n, NO_LANE, dtype=np.int64)
        at, _ = self.offsets["lane"]
        return np.frombuffer(self.data, dtype="<i2", count=self.n, offset=at).astype(np.int64)

    def texts(self, name: str) -> list[Any]:
        """A text column as a list of str and None."""
        at, size = self.offsets[name]
        if size == 0:  # vehicle_class, reported by no detection of the block
            return [None] * self.n
        values: list[Any] = orjson.loads(self.data[at : at + size])
        return values

    def sensors(self) -> list[str]:
        """The distinct sensor ids, sorted."""
        return sorted(set(self.texts("sensor_id")))


def detections_of(blocks: Sequence[Block], masks: Sequence[Any] | None = None) -> Detections:
    """The detections of `blocks` in order, each block's restricted to its boolean mask (None:
    all rows); no re-validation: they were valid when stored."""
    every = slice(None)
    picks = [every if m is None else m for m in masks] if masks else [every] * len(blocks)

    def numbers(name: str) -> FloatArray:
        parts = [b.floats(name)[m] for b, m in zip(blocks, picks, strict=True)]
        return np.concatenate(parts) if parts else np.empty(0)

    def texts(name: str) -> ObjectArray:
        values: list[Any] = []
        for b, m in zip(blocks, picks, strict=True):
            column = b.texts(name)
            values += column if isinstance(m, slice) else [column[i] for i in np.flatnonzero(m)]
        array = np.empty(len(values), dtype=object)
        array[:] = values
        return array

    lanes = [b.lanes()[m] for b, m in zip(blocks, picks, strict=True)]
    return Detections(
        position=numbers("position"),
        velocity=numbers("velocity"),
        timestamp=numbers("timestamp"),
        sensor_id=texts("sensor_id"),
        detection_id=texts("detection_id"),
        target=texts("target"),
        lane=np.concatenate(lanes) if lanes else np.empty(0, dtype=np.int64),
        length=numbers("length"),
        vehicle_class=texts("vehicle_class"),
    )
