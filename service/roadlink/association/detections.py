"""Detections as validated columnar arrays.

Every associator, the simulator, the CLI and the service exchange detections in this one shape, so
validation lives here and nowhere else: a `Detections` object is always valid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from roadlink.association.numbers import PLAIN_DECIMAL_HINT, strictly_parsable

CLUTTER = "clutter"
"""The reserved target label of a false alarm: a detection of no target."""

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
ObjectArray = npt.NDArray[np.object_]

# Beyond this magnitude, squares and sums of timestamps or positions lose all precision in float64
# (and are certainly not real road data); rejecting them keeps every later computation finite.
MAX_ABS_VALUE = 1e12

RawColumn = Sequence[object] | npt.NDArray[Any]
"""Unvalidated input: numbers, numeric strings, or anything else to be reported as an error."""


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the input: where (row, field) and what."""

    row: int | None
    field: str | None
    message: str

    def __str__(self) -> str:
        where = []
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        prefix = ", ".join(where)
        return f"{prefix}: {self.message}" if prefix else self.message


class DetectionError(ValueError):
    """The detections are invalid; `problems` says where and why (rows are 1-based data rows)."""

    MAX_LISTED = 20

    def __init__(self, problems: Sequence[Problem]) -> None:
        self.problems = list(problems)
        shown = "; ".join(str(p) for p in self.problems[: self.MAX_LISTED])
        more = len(self.problems) - self.MAX_LISTED
        if more > 0:
            shown += f"; and {more} more"
        super().__init__(shown)


@dataclass(frozen=True, eq=False)
class Detections:
    """Anonymous detections: one entry per sensor report, all arrays of equal length.

    `target` holds the true label where known (``None`` = unlabelled, ``"clutter"`` = false alarm);
    it is used only for scoring and by supervised associators.
    """

    position: FloatArray
    velocity: FloatArray
    timestamp: FloatArray
    sensor_id: ObjectArray
    detection_id: ObjectArray
    target: ObjectArray

    @classmethod
    def from_columns(
        cls,
        position: RawColumn,
        velocity: RawColumn,
        timestamp: RawColumn,
        sensor_id: Sequence[str | None] | None = None,
        detection_id: Sequence[str | None] | None = None,
        target: Sequence[str | None] | None = None,
    ) -> Detections:
        """Validate raw columns and build detections.

        Missing sensor ids are named after their position (``S1`` is the first sensor along the
        road); missing detection ids are generated as ``d1, d2, ...`` in input order. Raises
        `DetectionError` naming every offending row and field.
        """
        n = _common_length(position, velocity, timestamp, sensor_id, detection_id, target)
        problems: list[Problem] = []
        pos = _float_column("position", position, problems)
        vel = _float_column("velocity", velocity, problems)
        ts = _float_column("timestamp", timestamp, problems)
        for row in np.flatnonzero(np.isfinite(vel) & (vel <= 0)):
            problems.append(
                Problem(int(row) + 1, "velocity", f"must be > 0, got {float(vel[row])}")
            )
        if problems:
            raise DetectionError(problems)
        _check_travel_times(pos, vel, problems)
        if problems:
            raise DetectionError(problems)

        sensors = _sensor_ids(pos, sensor_id, problems)
        det_ids = _detection_ids(n, detection_id, problems)
        labels = _text_column(n, target)
        if problems:
            raise DetectionError(problems)
        # One sensor's detections are valid (a gateway per sensor is common); association needs
        # two sensor positions, and `associate` says so.
        return cls(pos, vel, ts, sensors, det_ids, labels)

    def __len__(self) -> int:
        return int(self.position.size)

    @property
    def labelled(self) -> npt.NDArray[np.bool_]:
        """Mask of detections whose true target (or clutter) is known."""
        return np.array([t is not None for t in self.target], dtype=bool)

    @property
    def reference_position(self) -> float:
        """Position of the reference sensor S1: the first along the road (smallest position)."""
        return float(self.position.min())

    @property
    def sensor_positions(self) -> FloatArray:
        """Distinct sensor positions, in road order."""
        return np.unique(self.position)

    def take(self, index: npt.ArrayLike) -> Detections:
        """A subset (or reordering) of these detections; no re-validation needed."""
        idx = np.asarray(index)
        return Detections(
            self.position[idx],
            self.velocity[idx],
            self.timestamp[idx],
            self.sensor_id[idx],
            self.detection_id[idx],
            self.target[idx],
        )

    def without_labels(self) -> Detections:
        """The same detections with every label removed (what an unsupervised associator sees)."""
        return Detections(
            self.position,
            self.velocity,
            self.timestamp,
            self.sensor_id,
            self.detection_id,
            np.full(len(self), None, dtype=object),
        )


def concatenate(parts: Sequence[Detections]) -> Detections:
    """Join several detection sets (e.g. batches) into one, keeping their order."""
    if not parts:
        raise DetectionError([Problem(None, None, "no detections")])
    return Detections(
        *(
            np.concatenate([getattr(p, name) for p in parts])
            for name in ("position", "velocity", "timestamp", "sensor_id", "detection_id", "target")
        )
    )


def _common_length(*columns: object) -> int:
    lengths = {len(c) for c in columns if c is not None}  # type: ignore[arg-type]
    if len(lengths) > 1:
        raise DetectionError([Problem(None, None, f"columns differ in length: {sorted(lengths)}")])
    return lengths.pop() if lengths else 0


def _float_column(name: str, values: object, problems: list[Problem]) -> FloatArray:
    out = _as_floats(values)
    not_number = np.zeros(0 if out is None else out.size, dtype=bool)
    if out is None:  # some entry is not a number: find which, one by one
        raw = list(values)  # type: ignore[call-overload]
        out = np.full(len(raw), np.nan)
        not_number = np.zeros(len(raw), dtype=bool)
        for i, value in enumerate(raw):
            number = _as_floats([value])
            if number is None:
                shown = value.item() if isinstance(value, np.generic) else value
                problems.append(
                    Problem(i + 1, name, f"must be a number in {PLAIN_DECIMAL_HINT}, got {shown!r}")
                )
                not_number[i] = True
            else:
                out[i] = number[0]
    for row in np.flatnonzero(~np.isfinite(out) & ~not_number):
        problems.append(Problem(int(row) + 1, name, f"must be finite, got {float(out[row])}"))
    for row in np.flatnonzero(np.isfinite(out) & (np.abs(out) > MAX_ABS_VALUE)):
        problems.append(
            Problem(
                int(row) + 1,
                name,
                f"magnitude {float(out[row]):g} is beyond the limit {MAX_ABS_VALUE:g}",
            )
        )
    return out


def _check_travel_times(
    position: FloatArray, velocity: FloatArray, problems: list[Problem]
) -> None:
    """Values valid one by one can still be absurd together: a speed so low that crossing the
    batch's span of road takes longer than any time roadlink represents (velocity 1e-300 over
    1e12 m overflows to infinity). Back-projection divides by speed, so refuse it here."""
    if position.size == 0:
        return
    span = float(position.max() - position.min())
    with np.errstate(divide="ignore", over="ignore"):
        crossing = span / velocity
    for row in np.flatnonzero(~(crossing <= MAX_ABS_VALUE))[:20]:
        problems.append(
            Problem(
                int(row) + 1,
                "velocity",
                f"{float(velocity[row]):g} is too slow for the batch's {span:g} of road: "
                f"crossing it would take {float(crossing[row]):g}, beyond the limit "
                f"{MAX_ABS_VALUE:g}",
            )
        )


def _as_floats(values: object) -> FloatArray | None:
    """The values as a flat float64 array, or None when any is not a number.

    Numbers, and text in plain decimal notation (`roadlink.association.numbers`). Booleans, None,
    bytes and text such as `30_0` or `٣٠` are not numbers, though Python and numpy would happily
    convert them.
    """
    if isinstance(values, np.ndarray):
        items = values.tolist() if values.dtype.kind in "OU" else None
    else:
        items = list(values)  # type: ignore[call-overload]
    if items is not None:
        kinds = set(map(type, items))  # at C speed: the common case is one kind
        if not kinds <= _NUMBER_TYPES:
            return None
        if str in kinds and not strictly_parsable(items if kinds == {str} else _texts(items)):
            return None
        values = items
    try:
        array = np.asarray(values)
    except ValueError:  # ragged: some entry is a sequence
        return None
    if array.ndim != 1 or array.dtype.kind not in "iufOU":
        return None
    try:
        return array.astype(np.float64)
    except (TypeError, ValueError):
        return None


def _texts(items: list[object]) -> list[str]:
    return [v for v in items if isinstance(v, str)]


# Exact types (bool is an int to Python, not a number to roadlink); numpy's scalars included.
_NUMBER_TYPES = frozenset(
    {int, float, str, np.str_, np.float64, np.float32, np.int64, np.int32, np.int16, np.int8}
)


def _text_column(n: int, given: Sequence[str | None] | None) -> ObjectArray:
    """Stripped strings, with None where the value is absent or blank."""
    out = np.full(n, None, dtype=object)
    if given is not None:
        for i, value in enumerate(given):
            text = None if value is None else str(value).strip()
            out[i] = text or None
    return out


def _sensor_ids(
    position: FloatArray, given: Sequence[str | None] | None, problems: list[Problem]
) -> ObjectArray:
    """Sensor ids, named after their position where absent; one id must mean one position."""
    distinct, rank = np.unique(position, return_inverse=True)
    generated = np.array([f"S{i + 1}" for i in range(distinct.size)], dtype=object)[rank]
    ids = _text_column(position.size, given)
    absent = np.array([v is None for v in ids], dtype=bool)
    ids[absent] = generated[absent]
    names, which = np.unique(ids.astype(str), return_inverse=True)
    lowest = np.full(names.size, np.inf)
    highest = np.full(names.size, -np.inf)
    np.minimum.at(lowest, which, position)
    np.maximum.at(highest, which, position)
    for k in np.flatnonzero(lowest != highest):
        rows = np.flatnonzero(which == k)
        first = rows[0]
        for row in rows[position[rows] != position[first]][:5]:
            problems.append(
                Problem(
                    int(row) + 1,
                    "sensor_id",
                    f"sensor '{names[k]}' is at position {position[first]:g} (row {first + 1}), "
                    f"not {position[row]:g}",
                )
            )
    return ids


def _detection_ids(
    n: int, given: Sequence[str | None] | None, problems: list[Problem]
) -> ObjectArray:
    ids = _text_column(n, given)
    absent = np.array([v is None for v in ids], dtype=bool)
    ids[absent] = np.array([f"d{i + 1}" for i in np.flatnonzero(absent)], dtype=object)
    names, first, counts = np.unique(ids.astype(str), return_index=True, return_counts=True)
    for k in np.flatnonzero(counts > 1)[:20]:
        rows = np.flatnonzero(ids.astype(str) == names[k])
        for row in rows[1:5]:
            problems.append(
                Problem(
                    int(row) + 1,
                    "detection_id",
                    f"'{names[k]}' repeats the id of row {first[k] + 1}",
                )
            )
    return ids
