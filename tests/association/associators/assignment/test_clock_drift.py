"""Sensors whose clocks drift while they report (`assignment/clock_drift.py`): followed over the
batch as the least-cost one-way path through each detection's misfits at a grid of offsets, set
right detection by detection and named; never on the committed cases on time."""

from __future__ import annotations

import dataclasses
import itertools
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.clock_drift import (
    ClockDrift,
    clock_drifts,
    drift_warnings,
    least_paths,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections

SUMO = Path(__file__).parents[3] / "data" / "sumo"
PARAMS = AssignmentParams()
MIDDLE = 5  # the middle sensor of the committed cases' 11
FIRST, LAST = 0, 10


def drifting(case: str, seconds: float, sensor: int = MIDDLE) -> Detections:
    """A committed SUMO case as reported where one sensor's clock gains `seconds` over the
    batch, evenly (none at the batch's first time, all of it at its last)."""
    d = read_detections_csv(SUMO / f"{case}.csv")
    positions = np.unique(d.position)
    first, last = d.timestamp.min(), d.timestamp.max()
    gained = seconds * (d.timestamp - first) / (last - first)
    late = np.where(d.position == positions[sensor], gained, 0.0)
    return dataclasses.replace(d, timestamp=d.timestamp + late)


def sawing(case: str, seconds: float, sensor: int = MIDDLE) -> Detections:
    """A committed SUMO case as reported where one sensor's clock gains `seconds` by the
    batch's middle time, is set right there, and gains them again by its last time (a fast
    clock that its time server corrects now and then)."""
    d = read_detections_csv(SUMO / f"{case}.csv")
    positions = np.unique(d.position)
    first, last = d.timestamp.min(), d.timestamp.max()
    gained = seconds * ((2.0 * (d.timestamp - first) / (last - first)) % 1.0)
    late = np.where(d.position == positions[sensor], gained, 0.0)
    return dataclasses.replace(d, timestamp=d.timestamp + late)


def brute_force(cost: np.ndarray, move: float, way: int, jump: float = np.inf) -> float:
    """The least total of every path through `cost` that moves `way` only but by jumps,
    enumerated."""
    steps, states = cost.shape
    best = np.inf
    for path in itertools.product(range(states), repeat=steps):
        moves = np.diff(path)
        step_costs = np.where(way * moves >= 0, np.minimum(move * np.abs(moves), jump), jump)
        best = min(best, float(cost[np.arange(steps), path].sum() + step_costs.sum()))
    return best


def test_the_least_path_is_the_least_of_every_one_way_path():
    rng = np.random.default_rng(0)
    # Costs of different lengths, found together (the shorter padded).
    costs = [rng.uniform(0.0, 5.0, size=(int(rng.integers(1, 6)), 4)) for _ in range(40)]
    paths, totals, jumps = least_paths(costs, 1.3)
    for cost, path, total, jumped in zip(costs, paths, totals, jumps, strict=True):
        moves = np.diff(path)
        assert np.all(moves >= 0) or np.all(moves <= 0)
        assert jumped.size == 0
        assert total == pytest.approx(
            cost[np.arange(len(path)), path].sum() + 1.3 * np.abs(moves).sum()
        )
        assert total == pytest.approx(min(brute_force(cost, 1.3, way) for way in (1, -1)))


def test_the_least_path_with_jumps_is_the_least_of_every_such_path():
    # A clock set right now and then drifts one way and jumps either way.
    rng = np.random.default_rng(1)
    costs = [rng.uniform(0.0, 6.0, size=(int(rng.integers(1, 7)), 4)) for _ in range(40)]
    paths, totals, jumps = least_paths(costs, 1.3, 2.5)
    for cost, path, total, jumped in zip(costs, paths, totals, jumps, strict=True):
        moves = np.diff(path)
        crawled = np.delete(moves, jumped)
        assert np.all(crawled >= 0) or np.all(crawled <= 0)
        assert total == pytest.approx(
            cost[np.arange(len(path)), path].sum() + 1.3 * np.abs(crawled).sum() + 2.5 * jumped.size
        )
        assert total == pytest.approx(min(brute_force(cost, 1.3, way, 2.5) for way in (1, -1)))
    assert any(jumped.size for jumped in jumps)


def test_a_drift_is_carried_on_at_its_slope_beyond_the_sample():
    drift = ClockDrift(1, np.array([10.0, 20.0, 30.0, 40.0, 50.0]), np.array([1, 2, 3, 4, 5.0]))
    assert drift.at(np.array([0.0, 25.0, 60.0])).tolist() == pytest.approx([0.0, 2.5, 6.0])


@pytest.mark.parametrize(
    ("case", "seconds", "sensor"),
    [
        ("sumo-dense", 10.0, MIDDLE),
        ("sumo-freeflow", -10.0, MIDDLE),
        # An end sensor has one segment to follow its clock by.
        ("sumo-dense", 10.0, FIRST),
        ("sumo-dense", -10.0, LAST),
        ("sumo-freeflow", 10.0, LAST),
        ("sumo-irregular", -10.0, FIRST),
    ],
)
def test_a_drifting_clock_is_followed_and_set_right(case, seconds, sensor):
    d = drifting(case, seconds, sensor)
    s = arrange(d.without_labels(), PARAMS)
    assert [drift.sensor for drift in s.clock_drifts] == [sensor]
    on_time = read_detections_csv(SUMO / f"{case}.csv").timestamp
    at = s.sensor == sensor
    # Set right to within a second (the lags' bins are half a second) away from the batch's
    # edges, where the drift is carried on at its slope.
    first, last = on_time.min(), on_time.max()
    inner = at & (on_time > first + 20.0) & (on_time < last - 20.0)
    assert np.abs(s.time[inner] - on_time[inner]).max() < 1.0
    assert np.median(np.abs(s.time[at] - on_time[at])) < 0.5
    # Each sensor's detections in time order, as every stage reads them.
    for k in range(s.positions.size):
        assert np.all(np.diff(s.sorted_time[s.start[k] : s.start[k + 1]]) >= 0)


@pytest.mark.parametrize(
    ("case", "seconds", "sensor", "least"),
    # On time: 95.4 and 99.2 %; before the drift was followed: 76.0 and 86.7 % (the middle
    # sensor), 88.3 and 93.9 % (the first, the last).
    [
        ("sumo-dense", 10.0, MIDDLE, 0.93),
        ("sumo-freeflow", -10.0, MIDDLE, 0.98),
        ("sumo-dense", 10.0, FIRST, 0.93),
        ("sumo-freeflow", -10.0, LAST, 0.98),
    ],
)
def test_a_drifting_clock_costs_the_association_little_and_is_named(case, seconds, sensor, least):
    d = drifting(case, seconds, sensor)
    result = associate(d, "assignment")
    (warning,) = [w for w in result.warnings if "drifts" in w]
    assert warning.startswith(f"the sensor at position {np.unique(d.position)[sensor]:g} stamps")
    assert result.metrics is not None and result.metrics.accuracy >= least


@pytest.mark.parametrize(
    ("case", "seconds", "sensor"),
    [
        ("sumo-freeflow", 10.0, MIDDLE),
        ("sumo-irregular", -10.0, MIDDLE),
        ("sumo-dense", 10.0, FIRST),
        ("sumo-junctions", 10.0, LAST),
    ],
)
def test_a_clock_set_right_now_and_then_is_followed_through_its_jump(case, seconds, sensor):
    d = sawing(case, seconds, sensor)
    s = arrange(d.without_labels(), PARAMS)
    (drift,) = s.clock_drifts
    assert drift.sensor == sensor and drift.jumps.size == 1
    on_time = read_detections_csv(SUMO / f"{case}.csv").timestamp
    first, last = on_time.min(), on_time.max()
    middle = 0.5 * (first + last)
    # Reported from the middle time to `seconds` after it, reports from before the clock was
    # set right and after it interleave: the jump lies among them.
    jumped = drift.time[drift.jumps[0] : drift.jumps[0] + 2].mean()
    assert min(middle, middle + seconds) - 2.0 < jumped < max(middle, middle + seconds) + 2.0
    # Set right to half a second mostly, and to a fifth of the 10 s gained nearly everywhere,
    # away from the batch's edges and from the jump, where the reports interleave.
    at = s.sensor == sensor
    inner = at & (on_time > first + 20.0) & (on_time < last - 20.0)
    inner &= (on_time < middle - 2.0) | (on_time > middle + abs(seconds) + 2.0)
    assert np.median(np.abs(s.time[inner] - on_time[inner])) < 0.5
    assert np.quantile(np.abs(s.time[inner] - on_time[inner]), 0.9) < 2.0
    for k in range(s.positions.size):
        assert np.all(np.diff(s.sorted_time[s.start[k] : s.start[k + 1]]) >= 0)


@pytest.mark.parametrize(
    ("case", "seconds", "sensor", "least"),
    # On time 94.3, 99.2 and 91.7 %; followed without jumps: 77.1, 95.3 and 87.2 %.
    [
        ("sumo-irregular", 10.0, MIDDLE, 0.91),
        ("sumo-freeflow", 10.0, MIDDLE, 0.98),
        ("sumo-junctions", 10.0, LAST, 0.90),
    ],
)
def test_a_clock_set_right_now_and_then_costs_the_association_little(case, seconds, sensor, least):
    result = associate(sawing(case, seconds, sensor), "assignment")
    (warning,) = [w for w in result.warnings if "drifts" in w]
    assert "its clock drifts and jumps (1 time, first about " in warning
    assert result.metrics is not None and result.metrics.accuracy >= least


def test_a_drift_is_carried_on_beyond_a_jump_at_the_slope_after_it():
    # Set right after the eighth report, inside the outer fifth: the slope beyond the last
    # report is the stretch's after the jump (0.05 a second), not the fifth's across it (-0.35).
    drift = ClockDrift(
        1,
        np.array([10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0, 80.0, 90.0, 100.0]),
        np.array([1.0, 2.0, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 0.5, 1.0]),
        np.array([7]),
    )
    assert drift.at(np.array([0.0, 35.0, 110.0])).tolist() == pytest.approx([0.0, 3.5, 1.5])


def test_a_neighbours_drift_is_the_neighbours_not_the_end_sensors():
    # The second sensor's drift moves the first segment's travel times as the first sensor's
    # would, and the second's as well: its own path fits better.
    s = arrange(drifting("sumo-dense", 10.0, FIRST + 1).without_labels(), PARAMS)
    assert [drift.sensor for drift in s.clock_drifts] == [FIRST + 1]


def test_an_end_sensor_is_not_followed_where_the_next_one_on_crawls():
    # Whose clock drifts, the first sensor's or the second's, only a third sensor where traffic
    # flows can tell: in a crawl there it is left alone.
    positions = np.array([0.0, 250.0, 500.0])
    rng = np.random.default_rng(2)
    start = np.sort(rng.uniform(0.0, 600.0, 400))
    speed = rng.uniform(20.0, 30.0, start.size)
    drift = 10.0 * start / 600.0
    crawl = np.full(start.size, 3.0)
    times = [start + drift, start + 250.0 / speed, start + 250.0 / speed + 250.0 / crawl]
    speeds = [speed, speed, crawl]
    order = [np.argsort(t) for t in times]
    found = clock_drifts(
        positions,
        [t[o] for t, o in zip(times, order, strict=True)],
        [v[o] for v, o in zip(speeds, order, strict=True)],
    )
    assert found == []
    # With traffic flowing at the third sensor, the first sensor's drift is followed.
    times[2] = start + 500.0 / speed
    speeds[2] = speed
    order = [np.argsort(t) for t in times]
    found = clock_drifts(
        positions,
        [t[o] for t, o in zip(times, order, strict=True)],
        [v[o] for v, o in zip(speeds, order, strict=True)],
    )
    assert [one.sensor for one in found] == [0]


@pytest.mark.parametrize(
    "case",
    [
        "sumo-dense",
        "sumo-freeflow",
        "sumo-irregular",
        "sumo-junctions",
        "sumo-faulty",
        "sumo-bottleneck",
        "sumo-queue",
        "sumo-stopgo",
        "sumo-arterial",
    ],
)
def test_clocks_on_time_never_drift(case):
    s = arrange(read_detections_csv(SUMO / f"{case}.csv").without_labels(), PARAMS)
    assert s.clock_drifts == ()


def test_a_constant_offset_is_no_drift():
    # A clock late by 10 s all batch long is one offset (`clocks`), not a drift.
    positions = np.array([0.0, 250.0, 500.0])
    rng = np.random.default_rng(1)
    start = np.sort(rng.uniform(0.0, 600.0, 300))
    speed = rng.uniform(20.0, 30.0, start.size)
    times = [start, start + 250.0 / speed + 10.0, start + 500.0 / speed]
    order = [np.argsort(t) for t in times]
    assert (
        clock_drifts(
            positions, [t[o] for t, o in zip(times, order, strict=True)], [speed[o] for o in order]
        )
        == []
    )


def test_a_drift_warning_names_the_offsets_at_both_ends():
    drift = ClockDrift(1, np.array([12.5, 60.0, 110.25]), np.array([0.0, 4.0, 8.04]))
    (warning,) = drift_warnings(np.array([0.0, 150.0, 300.0]), [drift])
    assert warning == (
        "the sensor at position 150 stamps its detections no later or earlier than the sensors "
        "either side of it about its report stamped 12.5, and 8.0 s later about its report "
        "stamped 110.25: its clock drifts; its times were set right for the association"
    )
