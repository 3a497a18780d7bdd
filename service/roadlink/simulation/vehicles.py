"""What a detector reads of a vehicle beyond its passage: its lane at each sensor, its length and
its class (`VehicleFeatures` in the config says which are reported).

Every vehicle is of one class, drawn from a motorway's mix, with a length uniform in its class's
range; both stay with it all along the road (the detector's measuring error is the fault model's
`length_noise`). It enters in a uniformly random lane and, between two consecutive sensors, moves
to a neighbouring lane with the configured probability.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.detections import FloatArray, IntArray, ObjectArray
from roadlink.simulation.config import SimulationConfig


@dataclass(frozen=True)
class VehicleClass:
    """A class of vehicles: its name, its share of the traffic and its range of lengths (m)."""

    name: str
    share: float
    length_range: tuple[float, float]


# A motorway's mix, roughly as European classifying counts report it.
VEHICLE_CLASSES = (
    VehicleClass("car", 0.80, (3.6, 5.4)),
    VehicleClass("van", 0.10, (5.0, 7.0)),
    VehicleClass("truck", 0.08, (8.0, 18.0)),
    VehicleClass("bus", 0.02, (12.0, 15.0)),
)

# Mixed with the simulation's seed into the features' own random stream, so that drawing them
# takes nothing from the traffic's: with the features off or on, the vehicles drive the same, and
# with them off every output is what it was before features existed.
FEATURE_STREAM = 0x1A9E5


@dataclass(frozen=True, eq=False)
class Features:
    """Per vehicle and sensor (n_targets x n_sensors), what its detections report: the lane
    (None if lanes are not reported), length (None if not) and class (None if not)."""

    lane: IntArray | None
    length: FloatArray | None
    vehicle_class: ObjectArray | None

    def columns(self) -> dict[str, np.ndarray]:
        """The reported features, flattened vehicle by vehicle, for `Passages`."""
        reported = {
            "lane": self.lane,
            "length": self.length,
            "vehicle_class": self.vehicle_class,
        }
        return {name: values.ravel() for name, values in reported.items() if values is not None}


def feature_rng(seed: int | None) -> np.random.Generator:
    """The features' own random stream (fresh entropy when the simulation has no seed)."""
    return np.random.default_rng(None if seed is None else [seed, FEATURE_STREAM])


def draw_features(config: SimulationConfig, n_sensors: int, rng: np.random.Generator) -> Features:
    """The lanes, lengths and classes the config asks for, of every vehicle at every sensor."""
    n = config.n_targets
    lane = None
    if config.lanes is not None:
        lane = draw_lanes(n, n_sensors, config.lanes, config.lane_change_probability, rng)
    if not (config.vehicle_lengths or config.vehicle_classes):
        return Features(lane, None, None)
    kind, length = draw_vehicles(n, rng)
    names = np.array([c.name for c in VEHICLE_CLASSES], dtype=object)
    return Features(
        lane,
        np.repeat(length[:, None], n_sensors, axis=1) if config.vehicle_lengths else None,
        np.repeat(names[kind][:, None], n_sensors, axis=1) if config.vehicle_classes else None,
    )


def draw_lanes(
    n: int, n_sensors: int, lanes: int, change: float, rng: np.random.Generator
) -> IntArray:
    """Each vehicle's lane at each sensor: uniform at the first, then a move to a neighbouring
    lane (either, with equal chance, where there are two) with probability `change` per segment."""
    start = rng.integers(lanes, size=n)
    if lanes == 1:
        return np.zeros((n, n_sensors), dtype=np.int64)
    moves = rng.random((n, n_sensors - 1)) < change
    sides = np.where(rng.random((n, n_sensors - 1)) < 0.5, -1, 1)
    out = np.empty((n, n_sensors), dtype=np.int64)
    out[:, 0] = start
    for k in range(1, n_sensors):
        step = np.where(moves[:, k - 1], sides[:, k - 1], 0)
        lane = out[:, k - 1] + step
        # At the road's edge the only neighbour is inwards: bounce back.
        out[:, k] = np.where((lane < 0) | (lane >= lanes), out[:, k - 1] - step, lane)
    return out


def draw_vehicles(n: int, rng: np.random.Generator) -> tuple[IntArray, FloatArray]:
    """Each vehicle's class (an index into VEHICLE_CLASSES) and its true length."""
    shares = np.array([c.share for c in VEHICLE_CLASSES])
    kind = rng.choice(len(VEHICLE_CLASSES), size=n, p=shares / shares.sum())
    lo = np.array([c.length_range[0] for c in VEHICLE_CLASSES])[kind]
    hi = np.array([c.length_range[1] for c in VEHICLE_CLASSES])[kind]
    return kind.astype(np.int64), rng.uniform(lo, hi)
