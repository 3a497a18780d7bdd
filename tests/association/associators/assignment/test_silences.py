"""A queue's silences (`assignment/silences.py`): no link over a sensor passes it inside a long
gap between two of its slow reports; a detector's outage in flowing traffic is bridged as before."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.associators.assignment.silences import (
    SILENCE_HEADWAYS,
    over_silence,
    silent_gaps,
)
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections, concatenate
from roadlink.simulation import preset, simulate

COMMITTED_SUMO = Path(__file__).parents[3] / "data" / "sumo"
PARAMS = AssignmentParams()


def sensor_reports(times: list[float], speed: float, position: float) -> Detections:
    return Detections.from_columns([position] * len(times), [speed] * len(times), times)


def road(middle: Detections) -> Detections:
    """Fast traffic at 0 and 400 m (20 m/s, a report every 2 s over 0-200 s, so the road's
    fastest median is 20 m/s), and `middle`'s reports at 200 m."""
    fast = np.arange(0.0, 200.0, 2.0).tolist()
    return concatenate([sensor_reports(fast, 20.0, 0.0), middle, sensor_reports(fast, 20.0, 400.0)])


# A report every 2 s, none between 60 and 140 s: 40 headways.
WITH_GAP = [t for t in np.arange(0.0, 200.0, 2.0).tolist() if not 60.0 < t < 140.0]
GAP_END = WITH_GAP.index(140.0)  # the place, among the middle sensor's reports, after the gap


def test_a_long_gap_between_slow_reports_is_a_silence():
    s = arrange(road(sensor_reports(WITH_GAP, 2.0, 200.0)), PARAMS)
    silent = s.silent_gaps
    middle = slice(int(s.start[1]), int(s.start[2]))
    assert np.flatnonzero(silent[middle]).tolist() == [GAP_END]
    assert not silent[: s.start[1]].any() and not silent[s.start[2] :].any()
    assert SILENCE_HEADWAYS < 80.0 / 2.0  # the gap is one


def test_a_gap_between_fast_reports_is_an_outage_not_a_silence():
    # A detector that failed for 80 s in flowing traffic: the vehicles passed it unseen.
    assert not silent_gaps(arrange(road(sensor_reports(WITH_GAP, 20.0, 200.0)), PARAMS)).any()


def test_gaps_of_a_few_headways_are_no_silence():
    uneven = np.cumsum(np.random.default_rng(0).exponential(2.0, 100)).tolist()
    assert not silent_gaps(arrange(road(sensor_reports(uneven, 2.0, 200.0)), PARAMS)).any()


def links(s, pairs: list[tuple[float, float]]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Links from the first sensor at time t_a to the last at t_b, over the middle one."""
    places = zip(s.sensor.tolist(), s.time.tolist(), strict=True)
    index = {(float(s.positions[k]), t): i for i, (k, t) in enumerate(places)}
    a = np.array([index[(0.0, t_a)] for t_a, _ in pairs])
    b = np.array([index[(400.0, t_b)] for _, t_b in pairs])
    return a, b, np.full(a.size, 2)


def test_a_link_that_could_only_have_passed_inside_the_silence_is_over_it():
    s = arrange(road(sensor_reports(WITH_GAP, 2.0, 200.0)), PARAMS)
    # At 20 m/s at most, a vehicle at 0 m at 70 s passes 200 m at 80 s at the earliest, and
    # one at 400 m at 120 s passed it at 110 s at the latest: inside the gap either way.
    # From 0 m at 40 s it may have passed before the gap began; to 400 m at 160 s, after.
    a, b, span = links(s, [(70.0, 120.0), (40.0, 120.0), (70.0, 160.0), (40.0, 160.0)])
    assert over_silence(s, a, b, span).tolist() == [True, False, False, False]
    # A link to the neighbouring sensor skips nothing.
    assert not over_silence(s, a, b, np.ones(a.size, dtype=np.int64)).any()


def test_the_committed_queue_links_no_vehicle_over_a_silence():
    # SUMO's queue (seed 0) stands still on sensors for minutes; vehicles waiting behind one
    # were linked over it to vehicles that had passed it before the queue stopped (all 122
    # links over a sensor wrong, 38.7 % of the detections grouped right; 42.5 % now).
    d = read_detections_csv((COMMITTED_SUMO / "sumo-queue.csv").read_bytes())
    result = associate(d, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.42
    s = arrange(d, PARAMS)
    order = np.lexsort((s.sensor, result.groups))
    same = result.groups[order[:-1]] == result.groups[order[1:]]
    same &= result.groups[order[:-1]] >= 0
    a, b = order[:-1][same], order[1:][same]
    span = s.sensor[b] - s.sensor[a]
    assert not over_silence(s, a, b, span).any()


def test_an_outage_in_flowing_traffic_is_still_bridged():
    # The paper's congested traffic (some vehicles under half the fastest sensor's median
    # speed) with its second sensor silent for the middle third of the batch: the vehicles
    # passing then are linked over it, as they were (98.0 % with every report).
    d = simulate(preset("congested"), seed=0).detections
    second = np.unique(d.position)[1]
    t = d.timestamp[d.position == second]
    lo, hi = np.quantile(t, [1 / 3, 2 / 3])
    out = d.take(
        np.flatnonzero(~((d.position == second) & (d.timestamp > lo) & (d.timestamp < hi)))
    )
    s = arrange(out, PARAMS)
    assert not s.silent_gaps.any()
    result = associate(out, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.97
