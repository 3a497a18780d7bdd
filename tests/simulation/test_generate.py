"""Algorithm 1 (`simulation/generate.py`): reproducible, with the kinematics, fluctuation, faults,
slow zones and ground truth it documents."""

import numpy as np
import pytest

from roadlink.association.detections import CLUTTER
from roadlink.simulation import PRESETS, SlowZone, preset, simulate


def per_target(d):
    labels = d.target.astype(str)
    return {t: np.flatnonzero(labels == t) for t in np.unique(labels) if t != CLUTTER}


def test_same_seed_same_data_other_seed_other_data():
    a = simulate(PRESETS["small"], seed=7).detections
    b = simulate(PRESETS["small"], seed=7).detections
    c = simulate(PRESETS["small"], seed=8).detections
    assert a.timestamp.tolist() == b.timestamp.tolist()
    assert a.timestamp.tolist() != c.timestamp.tolist()


def test_constant_model_has_exact_kinematics():
    d = simulate(preset("large", velocity_model="constant"), seed=2).detections
    for rows in per_target(d).values():
        assert np.ptp(d.velocity[rows]) == 0
        order = rows[np.argsort(d.position[rows])]
        travel = np.diff(d.timestamp[order])
        np.testing.assert_allclose(travel, 100.0 / d.velocity[order][1:], rtol=1e-9)


def test_ou_fluctuation_strength_is_as_documented():
    config = preset("large", n_targets=400, velocity_fluctuation=0.1)
    d = simulate(config, seed=0).detections
    relative = []
    for rows in per_target(d).values():
        order = rows[np.argsort(d.position[rows])]
        relative.append(d.velocity[order] / d.velocity[order][0] - 1.0)
    spread = np.std(np.concatenate(relative))
    # A 10% stationary std, seen over ~30 s against a 10 s correlation time: close to 0.1*sqrt(2)
    # at the far sensors, nearer 0 at the first ones.
    assert 0.05 < spread < 0.14


def test_faults_are_off_by_default_and_on_when_asked():
    assert all(t != CLUTTER for t in simulate(PRESETS["large"], seed=0).detections.target)
    config = preset(
        "large",
        n_targets=200,
        miss_probability=0.1,
        false_alarm_rate=0.05,
        duplicate_probability=0.05,
    )
    d = simulate(config, seed=0).detections
    clutter = int(np.sum(d.target == CLUTTER))
    real = len(d) - clutter
    # Expected: 2000 * 0.9 = 1800 kept, +5% duplicates = 1890; clutter ~ 5% of those.
    assert 1800 < real < 1980
    assert 60 < clutter < 140
    counts = [len(rows) for rows in per_target(d).values()]
    assert max(counts) > 10  # a duplicated detection exists
    assert min(counts) < 10  # a missed detection exists


def test_slow_zone_slows_targets_inside_it():
    zone = SlowZone(start=400.0, end=600.0, speed_factor=0.5)
    d = simulate(preset("small", n_targets=50, slow_zone=zone), seed=0).detections
    # The sensor at 500 stands inside the zone; those at 400 and 600 see targets enter and leave.
    inside = d.position == 500
    outside = (d.position < 400) | (d.position > 600)
    ratio = d.velocity[inside].mean() / d.velocity[outside].mean()
    assert 0.4 < ratio < 0.6


def test_trajectories_are_ground_truth_of_the_detections():
    sim = simulate(PRESETS["small"], seed=4, keep_trajectories=True)
    assert sim.trajectories is not None and len(sim.trajectories) == 10
    d = sim.detections
    for k, traj in enumerate(sim.trajectories):
        rows = np.flatnonzero(d.target == f"A{k + 1}")
        at = np.interp(d.timestamp[rows], traj.time, traj.position)
        np.testing.assert_allclose(at, d.position[rows], atol=2.0)


@pytest.mark.parametrize("name", ["large", "medium", "small"])
def test_paper_presets_follow_tables_one_to_three(name):
    config = PRESETS[name]
    d = simulate(config, seed=1).detections
    assert len(d) == 10 * 10
    assert sorted(set(d.position.tolist())) == [100.0 * i for i in range(10)]
    targets = per_target(d)
    assert len(targets) == 10
    lo, hi = config.velocity_range
    t_lo, t_hi = config.start_time_range
    for rows in targets.values():
        assert len(rows) == 10, "each target passes each sensor exactly once"
        first = rows[np.argmin(d.position[rows])]
        assert t_lo <= d.timestamp[first] <= t_hi  # enters at 0, where S1 stands
        order = rows[np.argsort(d.position[rows])]
        assert np.all(np.diff(d.timestamp[order]) > 0), "time increases along the road"
    # Velocities fluctuate around v0 ~ U[lo, hi], so stay near the range.
    assert lo * 0.7 < d.velocity.min() and d.velocity.max() < hi * 1.3
