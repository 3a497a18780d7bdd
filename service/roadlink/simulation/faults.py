"""What real detectors get wrong, one model for every simulator: misses, duplicates, false alarms
and measurement noise, applied to the passages a simulator recorded.

Both simulators (the paper's `generate` and SUMO's `sumo`) record true passages and then call
`apply_detector_faults`, so a fault means the same thing, drawn in the same order, whichever
traffic it is applied to. What differs between them is only what a false alarm's speed looks like:
the caller says, with a `FalseAlarmSpeeds` function.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from roadlink.association.detections import FloatArray

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
    timestamp_noise: float = Field(
        default=0.0, ge=0, description="Timestamp measurement error (std, seconds)."
    )


@dataclass(frozen=True, eq=False)
class Passages:
    """Parallel columns, one row a report: which sensor (an index), when, how fast, and whose
    (the label; the caller's `clutter` label for a false alarm)."""

    sensor: np.ndarray
    time: FloatArray
    speed: FloatArray
    target: np.ndarray

    def take(self, rows: np.ndarray) -> Passages:
        return Passages(self.sensor[rows], self.time[rows], self.speed[rows], self.target[rows])

    @staticmethod
    def concatenate(parts: list[Passages]) -> Passages:
        return Passages(
            np.concatenate([p.sensor for p in parts]),
            np.concatenate([p.time for p in parts]),
            np.concatenate([p.speed for p in parts]),
            np.concatenate([p.target for p in parts]),
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
    speed, time = passages.speed, passages.time
    if faults.velocity_noise:
        speed = speed * np.exp(faults.velocity_noise * rng.standard_normal(speed.size))
    if faults.timestamp_noise:
        time = time + faults.timestamp_noise * rng.standard_normal(time.size)
    return Passages(passages.sensor, time, speed, passages.target)


def _duplicate(passages: Passages, faults: DetectorFaults, rng: np.random.Generator) -> Passages:
    """A sensor reporting one passage twice: the copy a little later, its speed a little off."""
    twice = np.flatnonzero(rng.random(passages.time.size) < faults.duplicate_probability)
    copies = passages.take(twice)
    copies = Passages(
        copies.sensor,
        copies.time + rng.uniform(0.0, DUPLICATE_DELAY, size=twice.size),
        copies.speed * (1.0 + DUPLICATE_SPEED_ERROR * rng.standard_normal(twice.size)),
        copies.target,
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
    """Reports of no target, at each sensor in proportion to the passages it reported."""
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
        parts.append(Passages(sensor, time, speeds(int(k), count, passages.speed[at], rng), label))
    return Passages.concatenate(parts)
