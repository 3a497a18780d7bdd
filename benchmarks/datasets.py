"""Simulated data for the benchmarks, generated once per size and cached on disk.

Large sizes stretch the paper's "large" preset: the same speeds and the same density of traffic
(10 targets entering over 29 s, i.e. one every 2.9 s), with more targets and 50 sensors a
100 m apart (a 4.9 km road). 20 targets x 50 sensors is 10^3 detections; 20,000 x 50 is 10^6.
"""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np

from roadlink.association.detections import Detections
from roadlink.simulation import SimulationConfig, preset, simulate

CACHE = Path(__file__).resolve().parent / ".cache"
SENSORS = 50
SECONDS_PER_TARGET = 2.9  # the paper's large preset: 10 targets entering within 29 s
SCALE_SEED = 0


def scaled_config(n_targets: int) -> SimulationConfig:
    """The paper's large preset with `n_targets` targets, at its traffic density, on 50 sensors."""
    return preset(
        "large",
        n_targets=n_targets,
        sensor_positions=[100.0 * i for i in range(SENSORS)],
        start_time_range=(1.0, 1.0 + SECONDS_PER_TARGET * n_targets),
    )


def targets_for(n_detections: int) -> int:
    """Targets giving `n_detections` detections on 50 sensors (no missed detections)."""
    return max(2, n_detections // SENSORS)


def dataset_path(config: SimulationConfig, seed: int) -> Path:
    """Where the detections of (config, seed) are cached; the name hashes both."""
    key = json.dumps({"config": config.model_dump(mode="json"), "seed": seed}, sort_keys=True)
    digest = hashlib.sha256(key.encode()).hexdigest()[:16]
    return CACHE / f"sim-{config.n_targets}x{len(config.sensor_positions)}-{digest}.npz"


def cached_dataset(config: SimulationConfig, seed: int = SCALE_SEED) -> Path:
    """Simulate (config, seed) unless cached; the path of its .npz file."""
    path = dataset_path(config, seed)
    if not path.exists():
        detections = simulate(config, seed=seed).detections
        CACHE.mkdir(parents=True, exist_ok=True)
        partial = path.with_suffix(".partial.npz")
        save_detections(detections, partial)
        partial.replace(path)  # a run killed mid-write never leaves a truncated cache entry
    return path


def save_detections(detections: Detections, path: Path) -> None:
    """Write detections as plain arrays (no pickles); labels as strings, '' for unlabelled."""
    np.savez(
        path,
        position=detections.position,
        velocity=detections.velocity,
        timestamp=detections.timestamp,
        sensor_id=detections.sensor_id.astype(str),
        detection_id=detections.detection_id.astype(str),
        target=np.array(["" if t is None else t for t in detections.target], dtype=str),
    )


def load_detections(path: Path) -> Detections:
    """Read what `save_detections` wrote; it was valid when written, so it is not re-validated."""
    with np.load(path, allow_pickle=False) as data:
        target = data["target"].astype(object)
        target[target == ""] = None
        return Detections(
            data["position"],
            data["velocity"],
            data["timestamp"],
            data["sensor_id"].astype(object),
            data["detection_id"].astype(object),
            target,
        )
