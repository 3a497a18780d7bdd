"""Detections as validated columnar arrays.

Every associator, the simulator, the CLI and the service exchange detections in this one shape, so
validation lives here and nowhere else (one column at a time in `columns`, the optional detector
features in `feature_columns`): a `Detections` object is always valid.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import KW_ONLY, InitVar, dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np
import numpy.typing as npt

from roadlink.association.columns import (
    MAX_ABS_VALUE,
    DetectionError,
    FloatArray,
    IntArray,
    ObjectArray,
    Problem,
    RawColumn,
    float_column,
)
from roadlink.association.feature_columns import (
    NO_LANE,
    CodedTexts,
    classes_in_order,
    coded_class_column,
    lane_column,
    length_column,
)
from roadlink.association.parsed_texts import DeferredColumn

if TYPE_CHECKING:
    import polars as pl

CLUTTER = "clutter"
"""The reserved target label of a false alarm: a detection of no target."""


# The public names, with those of `columns` and `feature_columns` importers have always found here.
__all__ = [
    "CLUTTER",
    "COLUMNS",
    "NO_LANE",
    "DetectionError",
    "Detections",
    "FloatArray",
    "IntArray",
    "ObjectArray",
    "Problem",
    "RawColumn",
    "concatenate",
    "feature_arrays",
    "fill_unreported_features",
]


_DETECTION_IDS = DeferredColumn()
_TARGETS = DeferredColumn()
_SENSOR_IDS = DeferredColumn()
_DEFERRED = {"sensor_id": _SENSOR_IDS, "detection_id": _DETECTION_IDS, "target": _TARGETS}


@dataclass(frozen=True, eq=False)
class Detections:
    """Anonymous detections: one entry per sensor report, all arrays of equal length.

    `target` holds the true label where known (``None`` = unlabelled, ``"clutter"`` = false alarm);
    it is used only for scoring and by supervised associators.

    Three detector features are optional, per detection, since real detectors report more than
    the paper's (position, velocity, timestamp) and not every sensor measures each: `lane` (from
    0, `NO_LANE` where not reported), `length` (the vehicle's measured length in the position
    unit, NaN where not measured) and `vehicle_class` (a short word, None where not reported).
    """

    position: FloatArray
    velocity: FloatArray
    timestamp: FloatArray
    # Object arrays to every reader; the fast CSV reader may give them as the parser's
    # columns, made into the arrays on first read (`parsed_texts`). None has a default: the
    # descriptor says so (its class read raises AttributeError, as dataclasses documents for
    # descriptor-typed fields).
    sensor_id: DeferredColumn = _SENSOR_IDS
    detection_id: DeferredColumn = _DETECTION_IDS
    target: DeferredColumn = _TARGETS
    lane: IntArray = field(default=None)  # type: ignore[arg-type]
    length: FloatArray = field(default=None)  # type: ignore[arg-type]
    vehicle_class: ObjectArray = field(default=None)  # type: ignore[arg-type]
    # The classes as a detection block codes them, when the parser that built them had them
    # coded so (`CodedTexts.in_order`); not a column: see `class_codes`.
    _: KW_ONLY
    coded_classes: InitVar[CodedTexts | None] = None

    def __post_init__(self, coded_classes: CodedTexts | None) -> None:
        fill_unreported_features(self, self.position.size)
        object.__setattr__(self, "_coded_classes", coded_classes)

    @classmethod
    def from_columns(
        cls,
        position: RawColumn,
        velocity: RawColumn,
        timestamp: RawColumn,
        sensor_id: Sequence[str | None] | None = None,
        detection_id: Sequence[str | None] | None = None,
        target: Sequence[str | None] | None = None,
        lane: RawColumn | None = None,
        length: RawColumn | None = None,
        vehicle_class: Sequence[str | None] | CodedTexts | None = None,
    ) -> Detections:
        """Validate raw columns and build detections.

        Missing sensor ids are named after their position (``S1`` is the first sensor along the
        road); missing detection ids are generated as ``d1, d2, ...`` in input order. In the
        feature columns (`lane`, `length`, `vehicle_class`) None or a blank means "not reported"
        for that detection. Raises `DetectionError` naming every offending row and field.
        """
        n = _common_length(
            position,
            velocity,
            timestamp,
            sensor_id,
            detection_id,
            target,
            lane,
            length,
            vehicle_class,
        )
        problems: list[Problem] = []
        pos = float_column("position", position, problems)
        vel = float_column("velocity", velocity, problems)
        ts = float_column("timestamp", timestamp, problems)
        for row in np.flatnonzero(np.isfinite(vel) & (vel <= 0)):
            problems.append(
                Problem(int(row) + 1, "velocity", f"must be > 0, got {float(vel[row])}")
            )
        lanes = lane_column(n, lane, problems)
        lengths = length_column(n, length, problems)
        classes, coded = coded_class_column(n, vehicle_class, problems)
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
        return cls(
            pos, vel, ts, sensors, det_ids, labels, lanes, lengths, classes, coded_classes=coded
        )

    def __len__(self) -> int:
        return int(self.position.size)

    def parsed_texts(self, name: str) -> pl.Series | None:
        """The column `name` (`sensor_id`, `detection_id` or `target`) as the CSV parser made
        it (a polars String column, null where a label is empty), when it did: a writer that
        joins its text in polars, or the scoring, takes it so, without a str per row."""
        parsed = _DEFERRED[name].parsed(self)
        return None if parsed is None else parsed.series

    @property
    def labelled(self) -> npt.NDArray[np.bool_]:
        """Mask of detections whose true target (or clutter) is known."""
        return np.array([t is not None for t in self.target], dtype=bool)

    @property
    def has_lane(self) -> npt.NDArray[np.bool_]:
        """Mask of detections whose lane was reported."""
        return self.lane != NO_LANE

    @property
    def has_length(self) -> npt.NDArray[np.bool_]:
        """Mask of detections whose vehicle length was measured."""
        return ~np.isnan(self.length)

    @property
    def has_vehicle_class(self) -> npt.NDArray[np.bool_]:
        """Mask of detections whose vehicle class was reported."""
        return np.asarray(self.vehicle_class != None, dtype=bool)  # noqa: E711 (elementwise)

    @cached_property
    def features(self) -> tuple[str, ...]:
        """The optional feature columns that at least one detection reports, in contract order
        (found once: a result's writers ask several times, 10 ms each at 10^6 detections)."""
        present = (
            ("lane", self.has_lane),
            ("length", self.has_length),
            ("vehicle_class", self.has_vehicle_class),
        )
        return tuple(name for name, mask in present if bool(mask.any()))

    def feature_values(self, name: str) -> list[Any]:
        """One feature column (`lane`, `length` or `vehicle_class`) as plain Python values with
        None where not reported: the form JSON, CSV and SQL take."""
        values: list[Any] = getattr(self, name).tolist()
        if name == "lane":
            return [None if v == NO_LANE else v for v in values]
        if name == "length":
            return [None if v != v else v for v in values]  # NaN is the one value not itself
        return values

    def class_codes(self) -> CodedTexts:
        """The vehicle classes as a detection block stores them (`CodedTexts.in_order`: word 0
        None, then the classes in order of first appearance, and a code per detection): as the
        parser coded them when it did (a batch's few classes, not one per row), else coded here."""
        coded: CodedTexts | None = self.__dict__.get("_coded_classes")
        return coded if coded is not None else classes_in_order(self.vehicle_class.tolist())

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
        return Detections(*(getattr(self, name)[idx] for name in COLUMNS))

    def without_labels(self) -> Detections:
        """The same detections with every label removed (what an unsupervised associator sees)."""
        columns = self._stored(COLUMNS)
        columns["target"] = np.full(len(self), None, dtype=object)
        return Detections(**columns)

    def without_features(self) -> Detections:
        """The same detections as the paper's detector would report them: no lane, length or
        class (to measure what the features are worth)."""
        return Detections(**self._stored(COLUMNS[:6]))

    def _stored(self, names: Sequence[str]) -> dict[str, Any]:
        """The columns `names` as held: the ids and labels as the parser gave them, when it did
        (a copy of the detections need not make their strs)."""
        return {
            name: _DEFERRED[name].stored(self) if name in _DEFERRED else getattr(self, name)
            for name in names
        }

    def only_features(self, *names: str) -> Detections:
        """The same detections reporting only the named features (`lane`, `length`,
        `vehicle_class`): what a simpler detector would report, such as a single loop that
        knows its lane and measures no length."""
        unknown = set(names) - set(COLUMNS[6:])
        if unknown:
            raise ValueError(f"not a detector feature: {', '.join(sorted(unknown))}")
        return Detections(**self._stored((*COLUMNS[:6], *names)))


def fill_unreported_features(columns: object, n: int) -> None:
    """Set each feature column that is None on the frozen `columns` to "not reported" for all `n`
    rows, so that every reader sees the same arrays whether or not the input carried them."""
    unreported = {
        "lane": lambda: np.full(n, NO_LANE, dtype=np.int64),
        "length": lambda: np.full(n, np.nan),
        "vehicle_class": lambda: np.full(n, None, dtype=object),
    }
    for name, make in unreported.items():
        if getattr(columns, name) is None:
            object.__setattr__(columns, name, make())


def feature_arrays(
    lane: Sequence[int | None] | None = None,
    length: Sequence[float | None] | None = None,
    vehicle_class: Sequence[str | None] | None = None,
) -> dict[str, Any]:
    """The feature arrays of `Detections` from plain values with None where not reported (what
    `feature_values` gives), for a column that is absent as well: unvalidated, so only for
    values roadlink stored itself (a result document, the database)."""
    arrays: dict[str, Any] = {"lane": None, "length": None, "vehicle_class": None}
    if lane is not None:
        arrays["lane"] = np.array([NO_LANE if v is None else v for v in lane], dtype=np.int64)
    if length is not None:
        arrays["length"] = np.array([np.nan if v is None else v for v in length], dtype=float)
    if vehicle_class is not None:
        arrays["vehicle_class"] = np.array(list(vehicle_class), dtype=object)
    return arrays


COLUMNS = (
    "position",
    "velocity",
    "timestamp",
    "sensor_id",
    "detection_id",
    "target",
    "lane",
    "length",
    "vehicle_class",
)
"""Every column of `Detections`, in constructor order."""


def concatenate(parts: Sequence[Detections]) -> Detections:
    """Join several detection sets (e.g. batches) into one, keeping their order."""
    if not parts:
        raise DetectionError([Problem(None, None, "no detections")])
    return Detections(*(np.concatenate([getattr(p, name) for p in parts]) for name in COLUMNS))


def _common_length(*columns: object) -> int:
    lengths = {len(c) for c in columns if c is not None}  # type: ignore[arg-type]
    if len(lengths) > 1:
        raise DetectionError([Problem(None, None, f"columns differ in length: {sorted(lengths)}")])
    return lengths.pop() if lengths else 0


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


def _text_column(n: int, given: Sequence[str | None] | None) -> ObjectArray:
    """Stripped strings, with None where the value is absent or blank."""
    out = np.full(n, None, dtype=object)
    if given is not None:
        # Assigned as one list: an item assignment per row cost more than the rest of the read.
        out[:] = [None if value is None else str(value).strip() or None for value in given]
    return out


def _sensor_ids(
    position: FloatArray, given: Sequence[str | None] | None, problems: list[Problem]
) -> ObjectArray:
    """Sensor ids, named after their position where absent; one id must mean one position."""
    ids = _text_column(position.size, given)
    absent = np.array([v is None for v in ids], dtype=bool)
    if absent.any():
        distinct, rank = np.unique(position, return_inverse=True)
        generated = np.array([f"S{i + 1}" for i in range(distinct.size)], dtype=object)[rank]
        ids[absent] = generated[absent]
    names = ids.tolist()
    at = dict(zip(names, position.tolist(), strict=True))  # each id's last position
    if np.array_equal(np.fromiter(map(at.__getitem__, names), float, len(names)), position):
        return ids  # each id at one position (checked by hashing: the common case, fast)
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
    if len(set(ids.tolist())) == n:
        return ids  # no id repeats (checked by hashing: the common case, fast)
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
