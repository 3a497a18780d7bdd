"""Where each target is between its sensor passes: the aim of association.

Once detections are grouped, a target's detections are its passes: at each sensor it was at a known
position, at a known time, with a known velocity. Between two passes its position is estimated by
cubic Hermite interpolation: the one cubic per interval that matches both positions and both
velocities (`scipy.interpolate.CubicHermiteSpline` of position over time, with the velocities as
derivatives). Using the velocities, not only the positions, is what makes a speed change between
sensors show up as a curve instead of a kink; `docs/visualisation.md` measures the gain against
straight-line interpolation on the simulator's ground truth.

A target's interpolated path is its `Trajectory`, and its trip between two consecutive sensors a
`Leg` (the API and the CLI publish these as `track` and `segments`, their contract's words; see
`published_trajectory`).

Everything here returns plain frozen dataclasses of str / float / int (and tuples of them), so
`dataclasses.asdict` turns any of them into JSON-ready data.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from functools import cached_property
from typing import TYPE_CHECKING, Any

import numpy as np

from roadlink.association.detections import Detections, FloatArray

if TYPE_CHECKING:
    from scipy.interpolate import CubicHermiteSpline
from roadlink.association.numbers import parse_unsigned
from roadlink.association.result import AssociationResult

DEFAULT_SAMPLES = 100
"""Intervals a trajectory is sampled in when no step is given."""

MAX_SAMPLES = 100_000
"""More samples than this is a mistake in the step (and would be a denial of service over HTTP)."""


@dataclass(frozen=True)
class SensorPass:
    """A target passing one sensor: one detection, or several merged (see `Trajectory`)."""

    sensor_id: str
    position: float
    timestamp: float
    velocity: float
    detection_ids: tuple[str, ...]


@dataclass(frozen=True)
class TrajectoryPoint:
    """A target's estimated position and velocity at one time."""

    time: float
    position: float
    velocity: float


@dataclass(frozen=True)
class TargetPosition:
    """Where one target is at one time (what `positions_at` lists)."""

    target: str
    time: float
    position: float
    velocity: float


@dataclass(frozen=True)
class Leg:
    """A target's trip between two consecutive sensors it passed."""

    target: str
    from_sensor: str
    to_sensor: str
    from_position: float
    to_position: float
    departure: float
    arrival: float
    travel_time: float
    distance: float
    mean_speed: float
    """distance / travel_time; infinite when both passes share a time, negative when the pair runs
    against the road (both only happen when detections were grouped wrongly)."""


@dataclass(frozen=True)
class SampledTrajectory:
    """One target's passes, the legs between them, and its trajectory sampled over time."""

    target: str
    start: float
    end: float
    passes: tuple[SensorPass, ...]
    legs: tuple[Leg, ...]
    samples: tuple[TrajectoryPoint, ...]
    dropped_detection_ids: tuple[str, ...]
    monotone: bool


@dataclass(frozen=True, eq=False)
class Trajectory:
    """One target's passes in time order, and its interpolated position between them.

    Built by `build_trajectory`, which cleans the input so the interpolation is well posed:
    detections of one sensor are merged into one pass (mean time and velocity: with a duplicated
    report or two detections grouped together there is no telling which is right, and the mean is
    at most half their spread from either); of passes at different sensors sharing one time, which
    no moving target can do, only the first along the road is kept and the others are listed in
    `dropped_detection_ids`.

    `monotone` is False when the target goes backwards along the road between two passes: its
    detections were grouped wrongly, and its positions are then not to be trusted.
    """

    target: str
    passes: tuple[SensorPass, ...]
    dropped_detection_ids: tuple[str, ...] = ()
    _times: FloatArray = field(init=False, repr=False, compare=False)
    _positions: FloatArray = field(init=False, repr=False, compare=False)
    _velocities: FloatArray = field(init=False, repr=False, compare=False)

    def __post_init__(self) -> None:
        if not self.passes:
            raise ValueError(f"target {self.target} has no passes")
        times = np.array([p.timestamp for p in self.passes], dtype=np.float64)
        if np.any(np.diff(times) <= 0):
            raise ValueError(f"passes of target {self.target} must be in strictly increasing time")
        object.__setattr__(self, "_times", times)
        object.__setattr__(
            self, "_positions", np.array([p.position for p in self.passes], dtype=np.float64)
        )
        object.__setattr__(
            self, "_velocities", np.array([p.velocity for p in self.passes], dtype=np.float64)
        )

    @property
    def start(self) -> float:
        """Time of the first pass."""
        return float(self._times[0])

    @property
    def end(self) -> float:
        """Time of the last pass."""
        return float(self._times[-1])

    @property
    def monotone(self) -> bool:
        """Whether every pass is further along the road than the one before."""
        return bool(np.all(np.diff(self._positions) > 0))

    @cached_property
    def _spline(self) -> CubicHermiteSpline | None:
        if self._times.size < 2:
            return None
        # Imported on first use (pipeline.DEFERRED_IMPORTS): every CLI command would pay for it.
        from scipy.interpolate import CubicHermiteSpline

        return CubicHermiteSpline(self._times, self._positions, self._velocities, extrapolate=False)

    def covers(self, t: float) -> bool:
        """Whether the target is on the observed road at `t` (between its first and last pass)."""
        return self.start <= t <= self.end

    def point_at(self, t: float) -> TrajectoryPoint | None:
        """Estimated position and velocity at `t`; None outside [start, end]."""
        if not math.isfinite(t) or not self.covers(t):
            return None
        spline = self._spline
        if spline is None:  # a single pass: known at that one instant only
            return TrajectoryPoint(t, float(self._positions[0]), float(self._velocities[0]))
        return TrajectoryPoint(t, float(spline(t)), float(spline(t, 1)))

    def sample(self, times: Sequence[float] | FloatArray) -> tuple[TrajectoryPoint, ...]:
        """Estimated points at the given times; times outside [start, end] are left out."""
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        t = t[np.isfinite(t) & (t >= self.start) & (t <= self.end)]
        spline = self._spline
        if spline is None:
            return tuple(
                TrajectoryPoint(float(x), float(self._positions[0]), float(self._velocities[0]))
                for x in t
            )
        position, velocity = spline(t), spline(t, 1)
        return tuple(
            TrajectoryPoint(float(a), float(b), float(c))
            for a, b, c in zip(t, position, velocity, strict=True)
        )

    def positions(self, times: FloatArray) -> FloatArray:
        """Estimated positions at `times` as an array (NaN outside [start, end]); for plotting."""
        t = np.asarray(times, dtype=np.float64)
        spline = self._spline
        if spline is None:
            return np.where(t == self.start, self._positions[0], np.nan)
        return np.asarray(spline(t), dtype=np.float64)

    def legs(self) -> tuple[Leg, ...]:
        """Travel time, distance and mean speed between each pair of consecutive passes."""
        out = []
        for a, b in zip(self.passes, self.passes[1:], strict=False):
            travel = b.timestamp - a.timestamp
            distance = b.position - a.position
            out.append(
                Leg(
                    target=self.target,
                    from_sensor=a.sensor_id,
                    to_sensor=b.sensor_id,
                    from_position=a.position,
                    to_position=b.position,
                    departure=a.timestamp,
                    arrival=b.timestamp,
                    travel_time=travel,
                    distance=distance,
                    mean_speed=distance / travel,
                )
            )
        return tuple(out)


def build_trajectory(target: str, detections: Detections) -> Trajectory:
    """The trajectory of one target from its detections, in any order (see `Trajectory` for the
    cleaning)."""
    if len(detections) == 0:
        raise ValueError(f"target {target} has no detections")
    merged = _merge_by_sensor(detections)
    # Time order, and among equal times road order, so the one kept below is the first one.
    merged.sort(key=lambda p: (p.timestamp, p.position))
    passes: list[SensorPass] = []
    dropped: list[str] = []
    for p in merged:
        if passes and p.timestamp <= passes[-1].timestamp:
            dropped.extend(p.detection_ids)
        else:
            passes.append(p)
    return Trajectory(target, tuple(passes), tuple(dropped))


def target_trajectories(result: AssociationResult) -> list[Trajectory]:
    """The trajectory of every target of `result`, in target order (T1 first)."""
    d = result.detections
    return [build_trajectory(f"T{k + 1}", d.take(m)) for k, m in enumerate(result.target_members())]


def target_trajectory(result: AssociationResult, target: str) -> Trajectory:
    """The trajectory of one target, named as in the result JSON ("T3"); KeyError when unknown."""
    index = target_index(target, result.n_targets)
    members = result.target_members()[index]
    return build_trajectory(f"T{index + 1}", result.detections.take(members))


def sample_trajectory(
    result: AssociationResult | Trajectory, target: str | None = None, step: float | None = None
) -> SampledTrajectory:
    """A target's passes, legs and trajectory sampled every `step` from its first to last pass.

    Without `step` the span is cut into `DEFAULT_SAMPLES` equal intervals. The last pass is
    always among the samples. ValueError when `step` is not positive or gives more than
    `MAX_SAMPLES` samples.
    """
    if isinstance(result, Trajectory):
        trajectory = result
    else:
        if target is None:
            raise ValueError("name the target, e.g. 'T1'")
        trajectory = target_trajectory(result, target)
    span = trajectory.end - trajectory.start
    if step is not None and not (math.isfinite(step) and step > 0):
        raise ValueError(f"step must be a positive number, got {step}")
    if span == 0:
        times = np.array([trajectory.start])
    else:
        if step is None:
            step = span / DEFAULT_SAMPLES
        intervals = span / step  # infinite for a subnormal step: compared before flooring
        if not intervals < MAX_SAMPLES:
            raise ValueError(
                f"step {step:g} gives {intervals + 1:.0f} samples over {span:g}; "
                f"the limit is {MAX_SAMPLES}"
            )
        count = math.floor(intervals) + 1
        times = trajectory.start + step * np.arange(count)
        if times[-1] < trajectory.end:
            times = np.append(times, trajectory.end)
    return SampledTrajectory(
        target=trajectory.target,
        start=trajectory.start,
        end=trajectory.end,
        passes=trajectory.passes,
        legs=trajectory.legs(),
        samples=trajectory.sample(np.minimum(times, trajectory.end)),
        dropped_detection_ids=trajectory.dropped_detection_ids,
        monotone=trajectory.monotone,
    )


def published_trajectory(trajectory: SampledTrajectory) -> dict[str, Any]:
    """`trajectory` as JSON-ready data in the words the API and the CLI publish: its legs under
    `segments`, in their place (the contract's name; see ARCHITECTURE.md, "Names")."""
    return {
        ("segments" if key == "legs" else key): value for key, value in asdict(trajectory).items()
    }


def positions_at(
    result: AssociationResult | Sequence[Trajectory], t: float
) -> list[TargetPosition]:
    """Every target on the observed road at time `t` (between its first and last pass).

    Pass the trajectories (from `target_trajectories`) instead of the result to answer many times
    cheaply.
    """
    trajectories = target_trajectories(result) if isinstance(result, AssociationResult) else result
    out = []
    for trajectory in trajectories:
        point = trajectory.point_at(t)
        if point is not None:
            out.append(
                TargetPosition(trajectory.target, point.time, point.position, point.velocity)
            )
    return out


def leg_stats(result: AssociationResult | Sequence[Trajectory]) -> list[Leg]:
    """Travel time and mean speed of every target between each pair of consecutive sensors."""
    trajectories = target_trajectories(result) if isinstance(result, AssociationResult) else result
    return [s for trajectory in trajectories for s in trajectory.legs()]


def _merge_by_sensor(d: Detections) -> list[SensorPass]:
    """One pass per sensor position: several detections there are averaged (see `Trajectory`)."""
    passes = []
    for position in np.unique(d.position):
        at = np.flatnonzero(d.position == position)
        at = at[np.argsort(d.timestamp[at], kind="stable")]
        passes.append(
            SensorPass(
                sensor_id=str(d.sensor_id[at[0]]),
                position=float(position),
                timestamp=float(np.mean(d.timestamp[at])),
                velocity=float(np.mean(d.velocity[at])),
                detection_ids=tuple(str(i) for i in d.detection_id[at]),
            )
        )
    return passes


def target_index(target: str, n_targets: int) -> int:
    """The 0-based index of a target named as in the result JSON ("T3"; also "t3" or "3").

    KeyError naming the known targets when there is no such target.
    """
    name = target.strip()
    number = parse_unsigned(name[1:] if name[:1] in ("T", "t") else name, max_digits=12)
    if number is not None and 1 <= number <= n_targets:
        return number - 1
    known = f"T1..T{n_targets}" if n_targets else "none"
    raise KeyError(f"unknown target '{target}'; known: {known}")
