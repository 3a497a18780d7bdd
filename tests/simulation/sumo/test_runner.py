"""Running SUMO (`simulation/sumo/runner.py`): detector faults, and a labelled, reproducible run
(which needs Eclipse SUMO; skipped, saying so, without it)."""

from __future__ import annotations

import numpy as np
import pytest

from roadlink.association.detections import CLUTTER, Detections
from roadlink.simulation import sumo
from roadlink.simulation.sumo import (
    DetectorFaults,
    sumo_available,
    sumo_scenario,
    with_detector_faults,
)
from tests.helpers import travel_times

needs_sumo = pytest.mark.skipif(
    not sumo_available(), reason="Eclipse SUMO is not installed (pip install 'roadlink[sumo]')"
)


def test_detector_faults_miss_duplicate_and_invent_plausible_detections():
    rng = np.random.default_rng(0)
    n = 4000
    clean = Detections.from_columns(
        np.repeat([100.0, 300.0], n // 2),
        rng.uniform(20.0, 35.0, n),
        np.tile(np.sort(rng.uniform(0.0, 600.0, n // 2)), 2),
        sensor_id=["S1"] * (n // 2) + ["S2"] * (n // 2),
        target=[f"car.{i}" for i in range(n // 2)] * 2,
    )
    faults = DetectorFaults(miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.1)
    d = with_detector_faults(clean, faults, np.random.default_rng(1))
    labels = d.target.astype(str)
    real = labels != CLUTTER
    assert 0.85 * n < real.sum() < 1.05 * n  # 10% missed, ~9% of the rest duplicated
    passages = labels[real] + "@" + d.sensor_id[real].astype(str)
    counts = np.unique(passages, return_counts=True)[1]
    assert counts.max() == 2 and 0.07 < np.mean(counts == 2) < 0.13
    alarms = ~real
    assert 0.07 * n < alarms.sum() < 0.13 * n
    assert set(d.position[alarms]) == {100.0, 300.0}
    assert d.velocity[alarms].min() > 15.0 and d.velocity[alarms].max() < 45.0
    assert np.all(np.diff(d.position) >= 0)  # by sensor, then by time, as sensors log them


@needs_sumo
def test_sumo_end_to_end_gives_labelled_reproducible_tracks(tmp_path):
    scenario = sumo_scenario("sumo-freeflow", warmup=100.0, duration=60.0)
    d = sumo.run_sumo(scenario, seed=3, workdir=tmp_path)
    assert (tmp_path / "detections.xml").is_file()
    assert set(d.position) == set(scenario.sensor_positions)
    assert d.timestamp.min() >= 0.0 and d.timestamp.max() < 60.0
    assert d.labelled.all() and CLUTTER not in set(d.target)
    assert 10.0 < np.median(d.velocity) < 45.0
    # Every vehicle passes the sensors in road order, once each.
    for vehicle in np.unique(d.target.astype(str)):
        mine = d.target == vehicle
        assert np.all(np.diff(d.timestamp[mine]) > 0)
        assert np.unique(d.position[mine]).size == mine.sum()
    again = sumo.run_sumo(scenario, seed=3)
    np.testing.assert_array_equal(again.timestamp, d.timestamp)
    other = sumo.run_sumo(scenario, seed=4)
    assert len(other) != len(d) or not np.array_equal(other.timestamp, d.timestamp)


@needs_sumo
def test_traffic_lights_stop_the_vehicles_that_meet_red(tmp_path):
    scenario = sumo_scenario("sumo-arterial", warmup=200.0, duration=160.0)
    d = sumo.run_sumo(scenario, seed=1, workdir=tmp_path)
    assert 'programID="roadlink"' in (tmp_path / "signals.add.xml").read_text()
    free = travel_times(d, 100.0, 250.0)
    lights = travel_times(d, 550.0, 700.0)  # the first signal stands at 640 m
    assert np.percentile(lights, 90) > np.median(free) + 20.0
    assert np.percentile(free, 90) < 1.5 * np.median(free)


@needs_sumo
def test_vehicles_join_from_on_ramps_and_leave_by_off_ramps(tmp_path):
    scenario = sumo_scenario("sumo-junctions", warmup=150.0, duration=120.0)
    d = sumo.run_sumo(scenario, seed=2, workdir=tmp_path)
    assert (tmp_path / "road.con.xml").is_file()
    vehicles = d.target.astype(str)
    joined = np.char.find(vehicles, "-on") >= 0
    assert joined.sum() > 20  # they merge, not wait at the junction for good
    assert set(d.position[joined]) <= {1200.0, 1450.0, 1700.0, 1950.0, 2200.0, 2450.0, 2700.0}
    seen_last = {v: p for v, p in zip(vehicles, d.position, strict=True)}
    left = [v for v, p in seen_last.items() if p == 700.0 and "-on" not in v]
    assert len(left) > 10  # those that took the first off-ramp, seen last before it
