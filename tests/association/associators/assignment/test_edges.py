"""The batch's time window (`assignment/edges.py`): a link pays for the chance that its upstream
end's successor comes after the window closes, or its downstream end's predecessor passed before
it opened."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.edges import EDGE_SPREAD, WindowEdges
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import kinematic_model

CREEP = Path(__file__).parents[3] / "data" / "sumo-features" / "val-creep.csv"
PARAMS = AssignmentParams()
UNMATCHED = PARAMS.gate_cost / 2.0
# A crawl at 1 m/s over 100 m (100 s a segment) seen for 300 s: a vehicle every 10 s at each
# sensor, from t = 0 to t = 300.
TIMES = np.arange(0.0, 301.0, 10.0)


def crawl() -> Detections:
    n = TIMES.size
    return Detections.from_columns(
        position=np.repeat([0.0, 100.0], n),
        velocity=np.ones(2 * n),
        timestamp=np.tile(TIMES, 2),
    )


def edges_of(d: Detections) -> tuple[WindowEdges, np.ndarray]:
    s = arrange(d, PARAMS)
    return WindowEdges.of(s, kinematic_model(2, PARAMS), UNMATCHED), s.time


def at(times: np.ndarray, t: float, sensor: int) -> int:
    return int(np.flatnonzero(times == t)[sensor])


def test_far_from_the_edges_a_detection_pays_nothing() -> None:
    edges, times = edges_of(crawl())
    # Upstream at t = 0 its successor is due at 100 s, 200 s before the window closes (3.7
    # spreads): what it pays is below 1e-3. Downstream at 300 s, its predecessor is due at 200 s.
    assert edges.leaving[at(times, 0.0, 0)] < 1e-3
    assert edges.arriving[at(times, 300.0, 1)] < 1e-3
    # The first sensor's detections have no predecessor to pay for, the last's no successor.
    n = TIMES.size
    assert np.all(edges.arriving[:n] == 0) and np.all(edges.leaving[n:] == 0)


def test_a_partner_due_at_the_edge_costs_even_odds_and_one_due_beyond_costs_staying_alone() -> None:
    edges, times = edges_of(crawl())
    even = -2.0 * np.log(0.5)
    # Upstream at 200 s: its successor is due at 300 s, as the window closes.
    assert edges.leaving[at(times, 200.0, 0)] == pytest.approx(even)
    # Downstream at 100 s: its predecessor was due at 0 s, as the window opened.
    assert edges.arriving[at(times, 100.0, 1)] == pytest.approx(even)
    # Upstream at 290 s, due at 390 s: surely outside; at most what staying unmatched costs.
    assert edges.leaving[at(times, 290.0, 0)] == pytest.approx(UNMATCHED)
    assert edges.leaving[at(times, 300.0, 0)] == pytest.approx(UNMATCHED)


def test_the_cost_falls_as_the_room_grows_and_a_link_pays_both_ends() -> None:
    edges, times = edges_of(crawl())
    upstream = [at(times, t, 0) for t in (150.0, 200.0, 250.0)]
    assert np.all(np.diff(edges.leaving[upstream]) > 0)
    # At 150 s the room is 150 s for a travel time due in 100 s: -2 log P(z <= log(1.5) / spread).
    z = np.log(1.5) / EDGE_SPREAD
    assert edges.leaving[upstream[0]] == pytest.approx(-2.0 * np.log(norm_cdf(z)), rel=1e-6)
    a, b = np.array(upstream), np.array([at(times, 100.0, 1)] * 3)
    pairs = Pairs(a, b, np.zeros(3), np.zeros(3), np.ones(3), np.ones(3, dtype=np.int64))
    assert edges.cost(pairs) == pytest.approx(edges.leaving[a] + edges.arriving[b])


def norm_cdf(z: float) -> float:
    return 0.5 * math.erfc(-z / math.sqrt(2.0))


def test_in_free_flow_only_the_last_seconds_pay() -> None:
    # 30 m/s over 100 m (3.3 s a segment) in the same 300 s window.
    n = TIMES.size
    d = Detections.from_columns(
        position=np.repeat([0.0, 100.0], n),
        velocity=np.full(2 * n, 30.0),
        timestamp=np.tile(TIMES, 2),
    )
    edges, times = edges_of(d)
    paying = edges.leaving > 1e-3
    assert times[paying].min() >= 290.0
    assert (edges.arriving > 1e-3).sum() <= 1


@pytest.mark.slow
def test_a_crawl_cut_by_the_window_is_linked_better() -> None:
    # SUMO's val-creep (seed 0, with lane, length and class): 3 lanes into a zone limited to
    # 2.5 m/s, sensors every 200 m (80 s a segment in the zone), seen for 240 s. Measured 79.3 %
    # before a link paid for the window's edges, 81.9 % with that, 82.9 % once the tracks that
    # hold an anchored link taught the segments too (`learning.confident_detections`), 85.4 %
    # once the sweeps joined fragments there at the forward pass's gate (`refine.fragment_ends`).
    metrics = associate(read_detections_csv(CREEP.read_text()), "assignment").metrics
    assert metrics is not None and metrics.accuracy >= 0.83


def test_the_edges_at_several_caps_are_each_caps_own() -> None:
    # A forward pass and the sweep after it share the working-out: only the cap differs.
    d = read_detections_csv(CREEP.read_bytes()).without_labels()
    s = arrange(d, PARAMS)
    model = kinematic_model(s.positions.size, PARAMS)
    caps = (UNMATCHED, 2.0 * UNMATCHED, 0.5)
    for cap, both in zip(caps, WindowEdges.each(s, model, caps), strict=True):
        one = WindowEdges.of(s, model, cap)
        assert np.array_equal(both.leaving, one.leaving)
        assert np.array_equal(both.arriving, one.arriving)
        assert both.leaving.max() == cap


def test_the_detections_near_the_edges_are_each_sensors_own_search(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Every sensor's at once (binary searches among the arrivals as (sensor, time)), and sensor
    # by sensor where a time is NaN: the same detections.
    d = read_detections_csv(CREEP.read_bytes()).without_labels()
    s = arrange(d, PARAMS)
    model = kinematic_model(s.positions.size, PARAMS)
    at_once = WindowEdges.of(s, model, UNMATCHED)
    monkeypatch.setitem(s.__dict__, "arrival_keys", None)
    one_by_one = WindowEdges.of(s, model, UNMATCHED)
    assert np.count_nonzero(at_once.leaving) > 0 and np.count_nonzero(at_once.arriving) > 0
    assert np.array_equal(at_once.leaving, one_by_one.leaving)
    assert np.array_equal(at_once.arriving, one_by_one.arriving)


def test_a_sensor_that_stops_reporting_part_way_is_bridged_not_taken_for_the_windows_end():
    """The window is the batch's, every sensor's: a sensor whose last report came half-way
    through missed the vehicles after it, and links over it bridge them. Read as that sensor's
    own window's end, every detection upstream of it after then paid to be linked at all, and
    the tracks of the batch's second half broke there (74 %)."""
    d = simulate(preset("large", n_targets=50), seed=1).detections
    third = np.flatnonzero(d.position == np.unique(d.position)[2])
    late = third[d.timestamp[third] > np.median(d.timestamp[third])]
    quiet = d.take(np.setdiff1d(np.arange(len(d)), late))
    result = associate(quiet, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.80
    # The crawl's second sensor falls quiet half-way: what its first sensor's detections pay
    # for the window is what they paid with it reporting to the end.
    full = crawl()
    halfway = full.take(np.flatnonzero((full.position == 0.0) | (full.timestamp < 150.0)))
    before, _ = edges_of(full)
    after, _ = edges_of(halfway)
    first = np.arange(TIMES.size)  # the first sensor's rows, in both
    assert np.array_equal(after.leaving[first], before.leaving[first])
