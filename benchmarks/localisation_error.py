"""How far the localised position is from the truth: Hermite against straight-line interpolation.

For each preset, several simulated runs with ground truth (`keep_trajectories=True`); every target's
trajectory is built from its own true detections (the labels), so this measures interpolation
alone, not association. The error is taken at every simulator step strictly between a target's
first and last sensor pass. Run: `python -m benchmarks.localisation_error [--runs N]`.
"""

from __future__ import annotations

import argparse

import numpy as np

from roadlink.association.detections import FloatArray
from roadlink.association.localisation import build_trajectory
from roadlink.simulation import preset, simulate


def interpolation_errors(
    preset_name: str, seed: int, **overrides: object
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Absolute position errors of Hermite and linear interpolation, and each error's segment
    scale sigma_v * sqrt(2 * dt / tau) * dt (see `error_scale`), over one simulated run."""
    config = preset(preset_name, **overrides)
    sim = simulate(config, seed=seed, keep_trajectories=True)
    assert sim.trajectories is not None
    d = sim.detections
    hermite, linear, scale = [], [], []
    for k, truth in enumerate(sim.trajectories):
        mine = np.flatnonzero(d.target == f"A{k + 1}")
        trajectory = build_trajectory(f"A{k + 1}", d.take(mine))
        passes_t = np.array([p.timestamp for p in trajectory.passes])
        passes_x = np.array([p.position for p in trajectory.passes])
        inside = (truth.time > trajectory.start) & (truth.time < trajectory.end)
        t, x = truth.time[inside], truth.position[inside]
        hermite.append(np.abs(trajectory.positions(t) - x))
        linear.append(np.abs(np.interp(t, passes_t, passes_x) - x))
        interval = np.searchsorted(passes_t, t) - 1
        gap = np.diff(passes_t)[interval]
        scale.append(
            error_scale(
                config.velocity_fluctuation * float(np.mean(truth.velocity)),
                config.velocity_correlation_time,
                gap,
            )
        )
    return np.concatenate(hermite), np.concatenate(linear), np.concatenate(scale)


def error_scale(sigma_v: float, tau: float, gap: FloatArray) -> FloatArray:
    """The size of position error the velocity fluctuation allows over a gap between passes.

    An Ornstein-Uhlenbeck velocity with stationary std sigma_v and correlation time tau changes by
    about sigma_v * sqrt(2 * gap / tau) over a gap much shorter than tau; the interpolant knows the
    velocity at both ends only, so its position can be off by that velocity change times the gap.
    """
    return sigma_v * np.sqrt(2.0 * gap / tau) * gap


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--runs", type=int, default=20, help="simulated runs per preset")
    args = parser.parse_args()
    print(
        "| preset | samples | Hermite median | Hermite p99 | linear median | linear p99 "
        "| Hermite p99 / scale | linear p99 / scale |"
    )
    print("|---|---:|---:|---:|---:|---:|---:|---:|")
    for name in ("large", "medium", "small", "congested"):
        runs = [interpolation_errors(name, seed) for seed in range(args.runs)]
        h = np.concatenate([r[0] for r in runs])
        li = np.concatenate([r[1] for r in runs])
        s = np.concatenate([r[2] for r in runs])
        print(
            f"| {name} | {h.size} | {np.median(h):.3f} m | {np.quantile(h, 0.99):.3f} m "
            f"| {np.median(li):.3f} m | {np.quantile(li, 0.99):.3f} m "
            f"| {np.quantile(h / s, 0.99):.3f} | {np.quantile(li / s, 0.99):.3f} |"
        )


if __name__ == "__main__":
    main()
