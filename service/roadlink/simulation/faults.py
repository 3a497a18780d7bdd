"""What real detectors get wrong, one model for every simulator: misses, duplicates, false alarms
and measurement noise, applied to the passages a simulator recorded.

A passage may carry the detector features (lane, the vehicle's length and class); a simulator
that does not record them leaves them "not reported", and then no random number is drawn for
them, so that traffic without features is exactly what it was before features existed.

Both simulators (the paper's `generate` and SUMO's `sumo`) record true passages and then call
`apply_detector_faults`, so a fault means the same thing, drawn in the same order, whichever
traffic it is applied to. What differs between them is only what a false alarm's speed looks like:
the caller says, with a `FalseAlarmSpeeds` function.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from roadlink.association.detections import (
    NO_LANE,
    FloatArray,
    IntArray,
    ObjectArray,
    fill_unreported_features,
)

# A duplicate is the same passage reported again up to this long after it (s), its speed read
# again with this relative error: a detector that re-triggers on one vehicle.
DUPLICATE_DELAY = 0.5
DUPLICATE_SPEED_ERROR = 0.02


class DetectorFaults(BaseModel):
    """What real detectors get wrong, applied after the traffic is simulated. The one
    declaration of these settings: `SimulationConfig` has them as its own."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    miss_probability: float = Field(
        default=0.0, ge=0, lt=1, description="Chance that a sensor misses a passing target."
    )
    false_alarm_rate: float = Field(
        default=0.0,
        ge=0,
        le=10,
        description="False alarms per sensor, as a share of the targets it sees (label 'clutter').",
    )
    duplicate_probability: float = Field(
        default=0.0, ge=0, lt=1, description="Chance that a detection is reported twice."
    )
    velocity_noise: float = Field(
        default=0.0, ge=0, le=1, description="Velocity measurement error (std, share of velocity)."
    )
    velocity_bias: float = Field(
        default=0.0,
        ge=0,
        le=1,
        description="Each sensor's calibration error: every speed it reports is off by one "
        "factor of its own, lognormal with this std of its log (single loops, which infer "
        "speed from an assumed vehicle length: 5-15 %).",
    )
    timestamp_noise: float = Field(
        default=0.0, ge=0, description="Timestamp measurement error (std, seconds)."
    )
    length_noise: float = Field(
        default=0.0,
        ge=0,
        le=1,
        description="Vehicle length measurement error (std, share of length); loops: 0.05-0.10.",
    )


@dataclass(frozen=True, eq=False)
class Passages:
    """Parallel columns, one row a report: which sensor (an index), when, how fast, and whose
    (the label; the caller's `clutter` label for a false alarm); then, where the simulator records
    them, the lane (`NO_LANE` if not), the vehicle's length (NaN if not) and class (None if not)."""

    sensor: np.ndarray
    time: FloatArray
    speed: FloatArray
    target: np.ndarray
    lane: IntArray = field(default=None)  # type: ignore[arg-type]
    length: FloatArray = field(default=None)  # type: ignore[arg-type]
    vehicle_class: ObjectArray = field(default=None)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        fill_unreported_features(self, self.time.size)

    def take(self, rows: np.ndarray) -> Passages:
        return Passages(*(getattr(self, f.name)[rows] for f in fields(self)))

    def replace(self, **columns: np.ndarray) -> Passages:
        return Passages(
            **{f.name: columns.get(f.name, getattr(self, f.name)) for f in fields(self)}
        )

    @staticmethod
    def concatenate(parts: list[Passages]) -> Passages:
        return Passages(
            *(np.concatenate([getattr(p, f.name) for p in parts]) for f in fields(Passages))
        )


# (sensor index, how many, the speeds that sensor reported, rng) -> that many false-alarm speeds
FalseAlarmSpeeds = Callable[[int, int, FloatArray, np.random.Generator], FloatArray]


def apply_detector_faults(
    passages: Passages,
    faults: DetectorFaults,
    rng: np.random.Generator,
    *,
    false_alarm_speeds: FalseAlarmSpeeds,
    clutter: object,
    false_alarm_margin: float = 0.0,
) -> Passages:
    """Noise, then misses, duplicates and false alarms, in that order (rows are not sorted).

    False alarms come at uniformly random times in their sensor's busy period, widened by
    `false_alarm_margin` seconds on both sides, labelled `clutter`.
    """
    passages = _measurement_noise(passages, faults, rng)
    passages = passages.take(rng.random(passages.time.size) >= faults.miss_probability)
    passages = _duplicate(passages, faults, rng)
    return _false_alarms(passages, faults, rng, false_alarm_speeds, clutter, false_alarm_margin)


def _measurement_noise(
    passages: Passages, faults: DetectorFaults, rng: np.random.Generator
) -> Passages:
    speed, time, length = passages.speed, passages.time, passages.length
    if faults.velocity_noise:
        speed = speed * np.exp(faults.velocity_noise * rng.standard_normal(speed.size))
    if faults.velocity_bias:
        # One factor a sensor, drawn only when asked for, so other faults draw as before.
        n_sensors = int(passages.sensor.max(initial=-1)) + 1
        factors = np.exp(faults.velocity_bias * rng.standard_normal(n_sensors))
        speed = speed * factors[passages.sensor]
    if faults.timestamp_noise:
        time = time + faults.timestamp_noise * rng.standard_normal(time.size)
    if faults.length_noise and not np.isnan(length).all():
        length = length * np.exp(faults.length_noise * rng.standard_normal(length.size))
    return passages.replace(time=time, speed=speed, length=length)


def _duplicate(passages: Passages, faults: DetectorFaults, rng: np.random.Generator) -> Passages:
    """A sensor reporting one passage twice: the copy a little later, its speed a little off."""
    twice = np.flatnonzero(rng.random(passages.time.size) < faults.duplicate_probability)
    copies = passages.take(twice)
    copies = copies.replace(
        time=copies.time + rng.uniform(0.0, DUPLICATE_DELAY, size=twice.size),
        speed=copies.speed * (1.0 + DUPLICATE_SPEED_ERROR * rng.standard_normal(twice.size)),
    )
    return Passages.concatenate([passages, copies])


def _false_alarms(
    passages: Passages,
    faults: DetectorFaults,
    rng: np.random.Generator,
    speeds: FalseAlarmSpeeds,
    clutter: object,
    margin: float,
) -> Passages:
    """Reports of no target, at each sensor in proportion to the passages it reported; where
    passages carry features, a false alarm's are drawn from those its sensor reported."""
    if not faults.false_alarm_rate or passages.time.size == 0:
        return passages
    parts = [passages]
    for k in np.unique(passages.sensor):
        at = passages.sensor == k
        seen = passages.time[at]
        count = rng.poisson(faults.false_alarm_rate * seen.size)
        time = rng.uniform(seen.min() - margin, seen.max() + margin, size=count)
        label = np.full(count, clutter, dtype=passages.target.dtype)
        sensor = np.full(count, k, dtype=passages.sensor.dtype)
        speed = speeds(int(k), count, passages.speed[at], rng)
        features = _false_alarm_features(passages.take(np.flatnonzero(at)), count, rng)
        parts.append(Passages(sensor, time, speed, label, **features))
    return Passages.concatenate(parts)


def _false_alarm_features(
    seen: Passages, count: int, rng: np.random.Generator
) -> dict[str, np.ndarray]:
    """Lane, length and class of `count` false alarms: each one a sensor reported for a real
    passage (a loop that triggers falsely still reads some lane and length); none drawn where
    the sensor reported none."""
    features: dict[str, np.ndarray] = {}
    for name, reported in (
        ("lane", seen.lane != NO_LANE),
        ("length", ~np.isnan(seen.length)),
        ("vehicle_class", np.array([c is not None for c in seen.vehicle_class], dtype=bool)),
    ):
        if reported.any():
            features[name] = rng.choice(getattr(seen, name)[reported], size=count)
    return features
