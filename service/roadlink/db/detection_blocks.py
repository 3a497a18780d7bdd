"""A batch's detections as one columnar block: what the `detection_block` table stores per batch.

A batch is written once and read whole or by time window, never row by row, so its detections
are kept together, column by column, in upload order (row r is entry r - 1): storing a batch is
one row, not one per detection with its batch's and deployment's ids repeated, and deleting it
is deleting that row. Readers decode only the columns they need.

The layout (version 2), little-endian:
- a header: `RLDB`, the version (1 byte), flags (1 byte: which optional features the block
  holds, 1 lane, 2 length, 4 vehicle class, and how: see `_LANE_BYTE`, `_LENGTH_TENTHS`,
  `_CLASS_WIDE`, `_CLASS_WIDER`), the number of detections n (4 bytes), then the byte size of
  each of the four text parts (4 bytes each: sensor_id, detection_id, target, and the vehicle
  classes' vocabulary);
- position, velocity, timestamp: n float64 each;
- lane (n int8 or int16, `NO_LANE` where not reported), length (n int16 tenths of the unit,
  -1 where not measured, when every length is a whole number of tenths; else n float64, NaN
  where not measured) and the vehicle classes' codes (n uint8, uint16 or uint32: 0 where not
  reported, k for the vocabulary's k-th word), each only when some detection reports it;
- the text columns, each a JSON array of strings and nulls, then the vocabulary, a JSON array
  of the distinct classes (no bytes at all when no detection reports one).

Version 1 (still read) held lane as int16, length as float64, and the classes as a fourth JSON
text column in place of codes and vocabulary: a class per detection written out, 0.67 MB of
a 100,000-detection batch, where the codes and the vocabulary take 0.1 MB.

Numbers are stored as their bytes (or as tenths that divide back to the same float64), so
every value reads back exactly as it was validated.
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
VERSION = 2
_READABLE = (1, VERSION)
# Both versions' header: the fourth size is version 1's class text, version 2's vocabulary.
_HEADER = struct.Struct("<4sBBIIIII")
_LANE, _LENGTH, _CLASS = 1, 2, 4
# How version 2 stores a reported feature: the narrowest form that keeps every value.
_LANE_BYTE = 8  # lanes as int8 (every lane below 128), else int16
_LENGTH_TENTHS = 16  # lengths as int16 tenths, else float64
_CLASS_WIDE, _CLASS_WIDER = 32, 64  # class codes as uint16 or uint32, else uint8
_NO_TENTHS = -1
NUMBER_COLUMNS = ("position", "velocity", "timestamp")
TEXT_COLUMNS = ("sensor_id", "detection_id", "target", "vehicle_class")


def encode(detections: Detections) -> bytes:
    """The block of `detections` (validated, in upload order), in the current version."""
    d = detections
    lane_flags, lanes = _lane_bytes(d.lane)
    length_flags, lengths = _length_bytes(d.length)
    class_flags, codes, vocabulary = _class_bytes(d)
    texts = [orjson.dumps(getattr(d, name).tolist()) for name in TEXT_COLUMNS[:3]]
    texts.append(vocabulary)
    flags = lane_flags | length_flags | class_flags
    parts = [_HEADER.pack(MAGIC, VERSION, flags, len(d), *map(len, texts))]
    parts += [_float_bytes(d.position), _float_bytes(d.velocity), _float_bytes(d.timestamp)]
    return b"".join([*parts, lanes, lengths, codes, *texts])


def _float_bytes(values: FloatArray) -> bytes:
    return np.asarray(values, dtype="<f8").tobytes()


def _lane_bytes(lanes: IntArray) -> tuple[int, bytes]:
    """The lane flags and bytes (none when no lane is reported: valid lanes are at least
    `NO_LANE`, so the greatest says both whether any is and how wide they are)."""
    top = int(lanes.max()) if lanes.size else NO_LANE
    if top == NO_LANE:
        return 0, b""
    if top <= np.iinfo(np.int8).max:
        return _LANE | _LANE_BYTE, lanes.astype(np.int8).tobytes()
    return _LANE, np.asarray(lanes, dtype="<i2").tobytes()


def _length_bytes(lengths: FloatArray) -> tuple[int, bytes]:
    """The length flags and bytes: as tenths when each length is one that many tenths divide
    back to exactly (a detector's lengths mostly are, at a quarter of the bytes).

    Each test is one pass that lets NaN (not measured) through as it is counted: the least
    and greatest tenths ignore NaN, and a NaN is the one value not equal to itself divided
    back, so that the lengths divide back exactly when the only unequal ones are the NaNs."""
    unmeasured = int(np.count_nonzero(np.isnan(lengths)))
    if unmeasured == lengths.size:
        return 0, b""
    tenths = np.multiply(lengths, 10)
    np.round(tenths, out=tenths)
    fits = np.fmax.reduce(tenths) <= np.iinfo(np.int16).max and np.fmin.reduce(tenths) >= 0
    if fits and np.count_nonzero(tenths / 10 != lengths) == unmeasured:
        if unmeasured:
            tenths[np.isnan(tenths)] = _NO_TENTHS
        return _LENGTH | _LENGTH_TENTHS, tenths.astype("<i2").tobytes()
    return _LENGTH, _float_bytes(lengths)


def _class_bytes(detections: Detections) -> tuple[int, bytes, bytes]:
    """The class flags, codes and vocabulary: each detection's class as a code numbered in
    order of first appearance (`Detections.class_codes`: as the parser coded them, or one
    dict lookup a row)."""
    coded = detections.class_codes()
    if len(coded.words) <= 1:  # no detection reports a class
        return 0, b"", b""
    vocabulary = orjson.dumps(coded.words[1:])
    if len(coded.words) <= 1 << 8:
        return _CLASS, coded.codes.astype(np.uint8).tobytes(), vocabulary
    if len(coded.words) <= 1 << 16:
        return _CLASS | _CLASS_WIDE, coded.codes.astype("<u2").tobytes(), vocabulary
    return _CLASS | _CLASS_WIDER, coded.codes.astype("<u4").tobytes(), vocabulary


@dataclass(frozen=True)
class Block:
    """One stored block, decoded column by column on demand (see the module docstring)."""

    data: bytes
    n: int
    flags: int
    offsets: dict[str, tuple[int, int]]
    version: int = VERSION

    @classmethod
    def parse(cls, data: bytes) -> Block:
        """Read the header of a stored block (either version); raises ValueError on anything
        else."""
        if len(data) < _HEADER.size:
            raise ValueError("not a detection block: too short")
        magic, version, flags, n, *text_sizes = _HEADER.unpack_from(data)
        if magic != MAGIC or version not in _READABLE:
            raise ValueError(f"not a detection block of version {' or '.join(map(str, _READABLE))}")
        offsets: dict[str, tuple[int, int]] = {}
        at = _HEADER.size
        sizes = [(name, 8 * n) for name in NUMBER_COLUMNS]
        sizes += [(name, width * n) for name, width in _feature_widths(version, flags)]
        sizes += list(zip(TEXT_COLUMNS, text_sizes, strict=True))
        for name, size in sizes:
            offsets[name] = (at, size)
            at += size
        if at != len(data):
            raise ValueError("detection block of the wrong size")
        return cls(data, n, flags, offsets, version)

    def floats(self, name: str) -> FloatArray:
        """A number column (position, velocity, timestamp, length: NaN where not reported)."""
        if name == "length" and not self.flags & _LENGTH:
            return np.full(self.n, np.nan)
        at, _ = self.offsets[name]
        if name == "length" and self.flags & _LENGTH_TENTHS:
            tenths = np.frombuffer(self.data, dtype="<i2", count=self.n, offset=at)
            return np.where(tenths == _NO_TENTHS, np.nan, tenths / 10)
        return np.frombuffer(self.data, dtype="<f8", count=self.n, offset=at).astype(np.float64)

    def lanes(self) -> IntArray:
        """The lane column (`NO_LANE` where not reported)."""
        if not self.flags & _LANE:
            return np.full(self.n, NO_LANE, dtype=np.int64)
        at, _ = self.offsets["lane"]
        dtype = np.int8 if self.flags & _LANE_BYTE else np.dtype("<i2")
        return np.frombuffer(self.data, dtype=dtype, count=self.n, offset=at).astype(np.int64)

    def texts(self, name: str) -> list[Any]:
        """A text column as a list of str and None."""
        if name == "vehicle_class" and self.version > 1:
            return self._classes().tolist()
        at, size = self.offsets[name]
        if size == 0:  # vehicle_class, reported by no detection of the block
            return [None] * self.n
        values: list[Any] = orjson.loads(self.data[at : at + size])
        return values

    def _classes(self) -> ObjectArray:
        """Version 2's classes, one `str` per word of the vocabulary shared by its rows."""
        if not self.flags & _CLASS:
            return np.full(self.n, None, dtype=object)
        at, size = self.offsets["vehicle_class"]
        words = np.array([None, *orjson.loads(self.data[at : at + size])], dtype=object)
        start, _ = self.offsets["class_code"]
        dtype = _class_code_type(self.flags)
        return words[np.frombuffer(self.data, dtype=dtype, count=self.n, offset=start)]

    def sensors(self) -> list[str]:
        """The distinct sensor ids, sorted."""
        return sorted(set(self.texts("sensor_id")))


def _feature_widths(version: int, flags: int) -> list[tuple[str, int]]:
    """The feature columns a block holds before its texts, with their bytes per detection."""
    widths: list[tuple[str, int]] = []
    if flags & _LANE:
        widths.append(("lane", 1 if flags & _LANE_BYTE else 2))
    if flags & _LENGTH:
        widths.append(("length", 2 if flags & _LENGTH_TENTHS else 8))
    if version > 1 and flags & _CLASS:
        widths.append(("class_code", _class_code_type(flags).itemsize))
    return widths


def _class_code_type(flags: int) -> np.dtype[Any]:
    if flags & _CLASS_WIDER:
        return np.dtype("<u4")
    return np.dtype("<u2") if flags & _CLASS_WIDE else np.dtype(np.uint8)


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
