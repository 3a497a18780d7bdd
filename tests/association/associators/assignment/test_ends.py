"""Where vehicles leave or join the road between sensors (`assignment/ends.py`): read off the
tracks, told from tracks that merely broke and from queues that store vehicles, and what they
change on a motorway with junctions."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment import associator as assignment_associator
from roadlink.association.associators.assignment.ends import (
    SLOW_QUANTILE,
    RoadEnds,
    learn_road_ends,
    readable,
    slow_speeds,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.association.pipeline import associate
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import steady_vehicles

COMMITTED_SUMO = Path(__file__).parents[3] / "data" / "sumo"
PARAMS = AssignmentParams()
ROAD = [0.0, 250.0, 500.0, 750.0, 1000.0]
N = 120


def _traffic(speeds: np.ndarray | None = None) -> tuple[Detections, np.ndarray]:
    """N vehicles 2 s apart at 25-32 m/s past ROAD, sensor by sensor, and each row's vehicle."""
    rng = np.random.default_rng(7)
    speed = rng.uniform(25.0, 32.0, N) if speeds is None else speeds
    d = steady_vehicles(np.arange(N) * 2.0, speed, ROAD)
    return d, np.tile(np.arange(N), len(ROAD))


def _learn(d: Detections, track: np.ndarray, keep: np.ndarray) -> RoadEnds | None:
    """What `learn_road_ends` reads from the `keep`t rows' tracks (none near the window)."""
    s = arrange(d.take(np.flatnonzero(keep)), PARAMS)
    zeros = np.zeros(int(keep.sum()))
    return learn_road_ends(s, track[keep], zeros, zeros)


def test_a_sensor_past_which_vehicles_leave_and_one_before_which_they_join_are_found():
    d, vehicle = _traffic()
    sensor = np.repeat(np.arange(len(ROAD)), N)
    leaver = vehicle % 5 == 0  # a fifth leave between 250 and 500 m
    joiner = vehicle % 4 == 1  # a quarter join between 500 and 750 m
    keep = ~(leaver[vehicle] & (sensor >= 2)) & ~(joiner[vehicle] & (sensor <= 2))
    ends = _learn(d, vehicle, keep)
    assert ends is not None
    assert np.flatnonzero(ends.leaving).tolist() == [1]
    assert np.flatnonzero(ends.arriving).tolist() == [3]
    # 2 log (1 + excess share / typical share): a fifth of the vehicles against the 1 % floor.
    assert ends.leaving[1] == pytest.approx(2 * np.log1p(24 / (0.01 * N)), rel=1e-9)


def test_tracks_that_break_are_not_vehicles_leaving():
    """A link the tracks missed ends a track at one sensor and starts one at the next alike."""
    d, vehicle = _traffic()
    sensor = np.repeat(np.arange(len(ROAD)), N)
    track = vehicle.copy()
    broken = (vehicle % 5 == 0) & (sensor >= 2)
    track[broken] += N  # a fifth of the tracks break between 250 and 500 m
    assert _learn(d, track, np.ones(len(d), dtype=bool)) is None


def test_where_traffic_crawls_the_counts_are_not_read():
    """A queue stores vehicles between two sensors, so their counts need not match."""
    speeds = np.random.default_rng(7).uniform(25.0, 32.0, N)
    d, vehicle = _traffic(speeds)
    crawling = d.position == 500.0
    d = Detections.from_columns(
        d.position, np.where(crawling, 2.0, d.velocity), d.timestamp, target=list(d.target)
    )
    sensor = np.repeat(np.arange(len(ROAD)), N)
    keep = ~((vehicle % 5 == 0) & (sensor >= 2))
    assert _learn(d, vehicle, keep) is None


def test_on_a_motorway_with_junctions_vehicles_that_leave_and_join_are_not_linked(monkeypatch):
    """The committed seed-0 case of sumo-junctions (no lanes or lengths): without the road's
    ends, vehicles that left before one sensor were linked over it to vehicles that joined
    after it, and the vehicles that merged in took links from those they joined."""
    d = read_detections_csv((COMMITTED_SUMO / "sumo-junctions.csv").read_text())
    result = associate(d, "assignment")
    monkeypatch.setattr(assignment_associator, "learn_ends", lambda *args: None)
    before = associate(d, "assignment")
    assert result.metrics is not None and before.metrics is not None
    assert result.metrics.accuracy >= 0.90
    assert result.metrics.accuracy >= before.metrics.accuracy + 0.02


def test_a_passages_second_report_is_no_vehicle_leaving_or_joining():
    # A second detector at 500 m reports every vehicle again 0.05 s later: the copies, left
    # out of the tracks (each joins its twin's target at the end), read as tracks of their own
    # that end and start there, every vehicle leaving and joining (SUMO's free flow: 99.2 ->
    # 88.8 %). Counted as what they are, they say nothing.
    d, vehicle = _traffic()
    again = np.flatnonzero(d.position == 500.0)
    both = Detections.from_columns(
        np.r_[d.position, d.position[again]],
        np.r_[d.velocity, d.velocity[again]],
        np.r_[d.timestamp, d.timestamp[again] + 0.05],
    )
    track = np.r_[vehicle, np.full(again.size, -1)]
    copies = np.r_[np.zeros(len(d), dtype=bool), np.ones(again.size, dtype=bool)]
    s = arrange(both, PARAMS)
    zeros = np.zeros(len(both))
    read_as_tracks = learn_road_ends(s, track, zeros, zeros)
    assert read_as_tracks is not None
    assert read_as_tracks.leaving[2] > 0 and read_as_tracks.arriving[2] > 0
    assert learn_road_ends(s, track, zeros, zeros, copies) is None


def test_each_sensors_slow_speed_is_numpys_quantile():
    rng = np.random.default_rng(3)
    counts = [1, 2, 7, 40, 333]
    d = Detections.from_columns(
        np.repeat(100.0 * np.arange(len(counts)), counts),
        rng.uniform(1.0, 40.0, sum(counts)),
        rng.uniform(0.0, 100.0, sum(counts)),
    )
    s = arrange(d, PARAMS)
    expected = [np.quantile(s.speed[s.members(k)], SLOW_QUANTILE) for k in range(len(counts))]
    np.testing.assert_allclose(slow_speeds(s), expected, rtol=1e-15)


def test_a_paper_size_batch_skips_the_reading_it_could_not_make():
    # Ten vehicles: no sensor has MIN_COUNTED detections, so no share could stand out, and the
    # window's costs that the reading needs are not worked out (0.19 ms of a 7 ms job).
    d = simulate(preset("large"), seed=0).detections
    s = arrange(d, PARAMS)
    zeros = np.zeros(len(d))
    assert not readable(s)
    assert learn_road_ends(s, np.full(len(d), -1), zeros, zeros) is None
    assert readable(arrange(_traffic()[0], PARAMS))
