"""The paper's Algorithm 1: drive targets along the road and record what each sensor reports.

Each target i enters the road (position 0) at t0 ~ U[t_min, t_max] with velocity v0 ~ U[v_min,
v_max]; its velocity profile g(v0, t0), which the paper leaves unspecified, is here either constant
or an Ornstein-Uhlenbeck process around v0 (speed wanders and returns, as a driver's does). All
targets are integrated together on a fixed time step; a sensor records the exact crossing time
(interpolated within the step) and the velocity then. Faults are applied last.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.detections import CLUTTER, Detections, FloatArray
from roadlink.simulation.config import SimulationConfig

# A driver may slow to a crawl but never stops for good or reverses: the OU speed is floored.
MIN_SPEED_SHARE = 0.05


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
    time, speed = times.ravel(), speeds.ravel()
    time, speed = _measurement_noise(config, time, speed, rng)
    target, sensor, time, speed = _miss(config, target, sensor, time, speed, rng)
    target, sensor, time, speed = _duplicate(config, target, sensor, time, speed, rng)
    target, sensor, time, speed = _false_alarms(config, sensors, target, sensor, time, speed, rng)

    order = np.lexsort((time, sensor))  # as sensors log them: by sensor, then by time
    target, sensor, time, speed = target[order], sensor[order], time[order], speed[order]
    labels = np.where(target >= 0, np.char.add("A", (target + 1).astype(str)), CLUTTER)
    detections = Detections.from_columns(
        sensors[sensor],
        speed,
        time,
        sensor_id=[f"S{k + 1}" for k in sensor],
        target=labels.tolist(),
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


Columns = tuple[np.ndarray, np.ndarray, FloatArray, FloatArray]


def _measurement_noise(
    config: SimulationConfig, time: FloatArray, speed: FloatArray, rng: np.random.Generator
) -> tuple[FloatArray, FloatArray]:
    if config.velocity_noise:
        speed = speed * np.exp(config.velocity_noise * rng.standard_normal(speed.size))
    if config.timestamp_noise:
        time = time + config.timestamp_noise * rng.standard_normal(time.size)
    return time, speed


def _miss(
    config: SimulationConfig,
    target: np.ndarray,
    sensor: np.ndarray,
    time: FloatArray,
    speed: FloatArray,
    rng: np.random.Generator,
) -> Columns:
    keep = rng.random(time.size) >= config.miss_probability
    return target[keep], sensor[keep], time[keep], speed[keep]


def _duplicate(
    config: SimulationConfig,
    target: np.ndarray,
    sensor: np.ndarray,
    time: FloatArray,
    speed: FloatArray,
    rng: np.random.Generator,
) -> Columns:
    """A sensor reporting one passage twice: the copy a little later, its speed a little off."""
    twice = np.flatnonzero(rng.random(time.size) < config.duplicate_probability)
    copy_time = time[twice] + rng.uniform(0.0, 0.5, size=twice.size)
    copy_speed = speed[twice] * (1.0 + 0.02 * rng.standard_normal(twice.size))
    return (
        np.concatenate([target, target[twice]]),
        np.concatenate([sensor, sensor[twice]]),
        np.concatenate([time, copy_time]),
        np.concatenate([speed, copy_speed]),
    )


def _false_alarms(
    config: SimulationConfig,
    sensors: FloatArray,
    target: np.ndarray,
    sensor: np.ndarray,
    time: FloatArray,
    speed: FloatArray,
    rng: np.random.Generator,
) -> Columns:
    """Reports of no target, spread uniformly over each sensor's busy period (label -1)."""
    if not config.false_alarm_rate or time.size == 0:
        return target, sensor, time, speed
    parts: list[Columns] = [(target, sensor, time, speed)]
    lo, hi = config.velocity_range
    for k, position in enumerate(sensors):
        seen = time[sensor == k]
        if seen.size == 0:
            continue
        count = rng.poisson(config.false_alarm_rate * seen.size)
        factor = float(_zone_factor(config, np.array([position]))[0])
        parts.append(
            (
                np.full(count, -1),
                np.full(count, k),
                rng.uniform(seen.min() - 5.0, seen.max() + 5.0, size=count),
                rng.uniform(lo, hi, size=count) * factor,
            )
        )
    return tuple(np.concatenate(cols) for cols in zip(*parts, strict=True))  # type: ignore[return-value]
