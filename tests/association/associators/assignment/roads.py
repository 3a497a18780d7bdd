"""Small constructed roads for the assignment stages' tests: vehicles at steady speeds past a few
sensors, and the segment model that predicts exactly the kinematic travel time."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from roadlink.association.associators.assignment import AssignmentParams, SegmentModel, Tails
from roadlink.association.associators.assignment.sensors import KINEMATIC_SKEW
from roadlink.association.detections import Detections

GAUSSIAN = Tails(0.0, 3.0)
"""No tails: every residual costs r^2."""


def kinematic_model(
    n_sensors: int,
    params: AssignmentParams,
    *,
    max_span: int | None = None,
    tails: Tails = GAUSSIAN,
) -> SegmentModel:
    """A segment model with no bias, the kinematic skew, no speed change expected and the
    parameters' prior spreads, for every segment."""
    shape = (n_sensors, (params.max_skip + 1 if max_span is None else max_span) + 1)
    return SegmentModel(
        log_bias=np.zeros(shape),
        skew=np.full(shape, KINEMATIC_SKEW),
        time_spread=np.full(shape, params.travel_time_spread),
        log_speed_ratio=np.zeros(shape),
        speed_spread=np.full(shape, params.velocity_change_spread),
        preferred_speed_spread=params.velocity_change_spread,
        time_tails=tails,
        speed_tails=tails,
        level_tails=tails,
    )


def steady_vehicles(
    starts: Sequence[float], speeds: Sequence[float], positions: Sequence[float]
) -> Detections:
    """Vehicle i passes the first sensor at starts[i] and keeps speeds[i]; detections are listed
    sensor by sensor, vehicles in order within each, labelled V0, V1, ..."""
    start, speed = np.asarray(starts, dtype=float), np.asarray(speeds, dtype=float)
    at = np.asarray(positions, dtype=float)
    return Detections.from_columns(
        position=np.repeat(at, start.size),
        velocity=np.tile(speed, at.size),
        timestamp=np.concatenate([start + (x - at[0]) / speed for x in at]),
        target=[f"V{i}" for _ in at for i in range(start.size)],
    )


def sensor_cut(d: Detections, sensor: int, keep: int, *, first: bool = True) -> Detections:
    """The detections with the `sensor`-th sensor (in road order) keeping only its first (or,
    not `first`, its last) `keep` reports: a detector that stopped reporting early in the batch,
    or started late."""
    positions = np.unique(d.position)
    at = np.flatnonzero(d.position == positions[sensor])
    by_time = at[np.argsort(d.timestamp[at], kind="stable")]
    dropped = by_time[keep:] if first else by_time[:-keep]
    return d.take(np.setdiff1d(np.arange(len(d)), dropped))
