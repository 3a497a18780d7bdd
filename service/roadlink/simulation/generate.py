"""The paper's Algorithm 1: drive targets along the road and record what each sensor reports.

Each target i enters the road (position 0) at t0 ~ U[t_min, t_max] with velocity v0 ~ U[v_min,
v_max]; its velocity profile g(v0, t0), which the paper leaves unspecified, is here either constant
or an Ornstein-Uhlenbeck process around v0 (speed wanders and returns, as a driver's does). All
targets are integrated together on a fixed time step; a sensor records the exact crossing time
(interpolated within the step) and the velocity then. When the config asks for them, every
detection also reports its vehicle's lane, length and class (`roadlink.simulation.vehicles`).
Faults are applied last, by the fault model that the SUMO simulator shares
(`roadlink.simulation.faults`).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.detections import CLUTTER, Detections, FloatArray
from roadlink.simulation.config import SimulationConfig
from roadlink.simulation.faults import Passages, apply_detector_faults
from roadlink.simulation.vehicles import draw_features, feature_rng

# A driver may slow to a crawl but never stops for good or reverses: the OU speed is floored.
MIN_SPEED_SHARE = 0.05

# False alarms come this long (s) before a sensor's first passage or after its last, too.
FALSE_ALARM_MARGIN = 5.0


@dataclass(frozen=True, eq=False)
class Trajectory:
    """The ground truth of one target: its position and velocity over time."""

    time: FloatArray
    position: FloatArray
    velocity: FloatArray


@dataclass(frozen=True, eq=False)
class Simulation:
    """Labelled detections (target labels A1..AN, false alarms 'clutter'), with ground truth."""

    detections: Detections
    trajectories: list[Trajectory] | None


def simulate(
    config: SimulationConfig, seed: int | None = None, keep_trajectories: bool = False
) -> Simulation:
    """Run Algorithm 1 once. The same config and seed always give the same detections."""
    rng = np.random.default_rng(seed)
    sensors = np.sort(np.asarray(config.sensor_positions, dtype=np.float64))
    v0 = rng.uniform(*config.velocity_range, size=config.n_targets)
    t0 = rng.uniform(*config.start_time_range, size=config.n_targets)
    times, speeds, trajectories = _drive(config, sensors, v0, t0, rng, keep_trajectories)

    target = np.repeat(np.arange(config.n_targets), sensors.size)
    sensor = np.tile(np.arange(sensors.size), config.n_targets)
    features = draw_features(config, sensors.size, feature_rng(seed))
    passages = Passages(sensor, times.ravel(), speeds.ravel(), target, **features.columns())
    passages = _detector_faults(config, sensors, passages, rng)
    # As sensors log them: by sensor, then by time.
    passages = passages.take(np.lexsort((passages.time, passages.sensor)))
    target, sensor = passages.target, passages.sensor
    labels = np.where(target >= 0, np.char.add("A", (target + 1).astype(str)), CLUTTER)
    detections = Detections.from_columns(
        sensors[sensor],
        passages.speed,
        passages.time,
        sensor_id=[f"S{k + 1}" for k in sensor],
        target=labels.tolist(),
        # Only the features the config reports: the others stay absent, as the paper's are.
        **{name: getattr(passages, name) for name in features.columns()},
    )
    return Simulation(detections, trajectories)


def _drive(
    config: SimulationConfig,
    sensors: FloatArray,
    v0: FloatArray,
    t0: FloatArray,
    rng: np.random.Generator,
    keep: bool,
) -> tuple[FloatArray, FloatArray, list[Trajectory] | None]:
    """Integrate every target until it has passed the last sensor; crossing times and speeds."""
    n, dt = v0.size, config.time_step
    passing_time = np.full((n, sensors.size), np.nan)
    passing_speed = np.full((n, sensors.size), np.nan)
    x = np.zeros(n)
    desired = v0.copy()
    elapsed = 0.0
    next_sensor = np.zeros(n, dtype=np.int64)
    decay = np.exp(-dt / config.velocity_correlation_time)
    kick = config.velocity_fluctuation * v0 * np.sqrt(1.0 - decay**2)
    history: list[tuple[float, FloatArray, FloatArray]] = []
    while (next_sensor < sensors.size).any():
        speed = desired * _zone_factor(config, x)
        if keep:
            history.append((elapsed, x.copy(), speed.copy()))
        x_new = x + speed * dt
        _record_crossings(
            sensors, x, x_new, speed, elapsed, dt, next_sensor, passing_time, passing_speed
        )
        x, elapsed = x_new, elapsed + dt
        if config.velocity_model == "ou":
            desired = v0 + (desired - v0) * decay + kick * rng.standard_normal(n)
            np.maximum(desired, MIN_SPEED_SHARE * v0, out=desired)
    trajectories = None
    if keep:
        history.append((elapsed, x.copy(), (desired * _zone_factor(config, x)).copy()))
        clock = np.array([h[0] for h in history])
        xs = np.array([h[1] for h in history])
        vs = np.array([h[2] for h in history])
        trajectories = [Trajectory(clock + t0[i], xs[:, i], vs[:, i]) for i in range(n)]
    return passing_time + t0[:, None], passing_speed, trajectories


def _record_crossings(
    sensors: FloatArray,
    x: FloatArray,
    x_new: FloatArray,
    speed: FloatArray,
    elapsed: float,
    dt: float,
    next_sensor: np.ndarray,
    passing_time: FloatArray,
    passing_speed: FloatArray,
) -> None:
    """Record every sensor crossed in this step (several, if sensors are closer than one step)."""
    while True:
        idx = np.flatnonzero(next_sensor < sensors.size)
        at = sensors[next_sensor[idx]]
        crossed = at <= x_new[idx]
        if not crossed.any():
            return
        i, s = idx[crossed], next_sensor[idx[crossed]]
        step = np.maximum(x_new[i] - x[i], 1e-12)
        passing_time[i, s] = elapsed + dt * np.clip((sensors[s] - x[i]) / step, 0.0, 1.0)
        passing_speed[i, s] = speed[i]
        next_sensor[i] += 1


def _zone_factor(config: SimulationConfig, x: FloatArray) -> FloatArray:
    zone = config.slow_zone
    if zone is None:
        return np.ones_like(x)
    return np.where((x >= zone.start) & (x < zone.end), zone.speed_factor, 1.0)


def _detector_faults(
    config: SimulationConfig, sensors: FloatArray, passages: Passages, rng: np.random.Generator
) -> Passages:
    """The config's faults; a false alarm's speed is any the target could have had there."""
    lo, hi = config.velocity_range
    factor = _zone_factor(config, sensors)

    def speeds(k: int, count: int, _seen: FloatArray, rng: np.random.Generator) -> FloatArray:
        return rng.uniform(lo, hi, size=count) * factor[k]

    return apply_detector_faults(
        passages,
        config.faults,
        rng,
        false_alarm_speeds=speeds,
        clutter=-1,
        false_alarm_margin=FALSE_ALARM_MARGIN,
    )
