"""Learning the segments (`assignment/learning.py`): which end of a segment explains its
travel time, per segment and from the links alone."""

import numpy as np
import pytest

from roadlink.association import Detections
from roadlink.association.associators.assignment import AssignmentParams, learning
from roadlink.association.associators.assignment.anchors import Anchors
from roadlink.association.associators.assignment.learning import (
    best_skews,
    confident_detections,
    learn_segments,
)
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.sensors import arrange
from tests.association.associators.assignment.roads import sensor_cut


def braking(seed: int, n_vehicles: int = 150) -> Detections:
    """Vehicles about a second apart keep their own speed (25-35 m/s) up to 480 m, then brake,
    each to a speed of its own (10-16 m/s), just before the sensor at 500 m, and keep it to the
    last sensor at 750 m; sensors measure speed to 1 %. The segment 250 -> 500 m is driven almost
    all at the first speed: the kinematic prediction, which weighs both ends' speeds alike, is
    off by 30-60 %, differently for every vehicle."""
    rng = np.random.default_rng(seed)
    start = np.cumsum(rng.exponential(1.0, n_vehicles))
    fast = rng.uniform(25.0, 35.0, n_vehicles)
    slow = rng.uniform(10.0, 16.0, n_vehicles)
    times = [start, start + 250.0 / fast, start + 480.0 / fast + 20.0 * 2.0 / (fast + slow)]
    times.append(times[2] + 250.0 / slow)
    speeds = [fast, fast, slow, slow]
    return Detections.from_columns(
        np.repeat([0.0, 250.0, 500.0, 750.0], n_vehicles),
        np.concatenate([v * np.exp(0.01 * rng.standard_normal(n_vehicles)) for v in speeds]),
        np.concatenate(times),
        target=[f"V{i}" for _ in range(4) for i in range(n_vehicles)],
    )


def test_learning_finds_which_end_of_a_segment_explains_its_travel_time():
    d = braking(0)
    params = AssignmentParams()
    s = arrange(d, params)
    _, truth = np.unique(d.target, return_inverse=True)
    prior = segment_prior(s, params.max_skip + 1, params)
    model = learn_segments(s, truth, params, prior)
    # Braking at 480 m: the segment 250 -> 500 m is explained by the speed at 250 m, and then
    # predicted to a few per cent (the symmetric prediction is off by 30-60 %).
    assert model.skew[1, 1] <= 0.1
    assert model.time_spread[1, 1] <= 0.03
    # Steady speeds: both ends explain the time alike, and the kinematic prediction stands.
    assert model.skew[0, 1] == model.skew[2, 1] == 0.5


def test_best_skews_find_which_end_explains_the_travel_time():
    rng = np.random.default_rng(1)
    n = 200
    dx = np.full(n, 250.0)
    v_a, v_b = rng.uniform(25.0, 35.0, n), rng.uniform(10.0, 16.0, n)
    noise = np.exp(0.01 * rng.standard_normal(n))
    # One long segment (its medians taken alone) and two short ones (theirs side by side, to
    # two steps of the grid).
    whole, halves = [np.arange(n)], [np.arange(0, 50), np.arange(50, 100)]
    for w in (0.0, 0.2, 0.8, 1.0):
        dt = 1.3 * dx * ((1.0 - w) / v_a + w / v_b) * noise
        assert best_skews(dt, dx, v_a, v_b, whole) == pytest.approx([w], abs=0.05)
        assert best_skews(dt, dx, v_a, v_b, halves) == pytest.approx([w, w], abs=0.1)
    # Where both ends' speeds explain the time alike, the kinematic prediction stands.
    same = rng.uniform(25.0, 35.0, n)
    dt = dx / same * np.exp(0.02 * rng.standard_normal(n))
    assert best_skews(dt, dx, same, same * np.exp(0.02 * rng.standard_normal(n)), whole) == [0.5]
    too_few = [np.arange(2)]  # links to say
    assert best_skews(dt, dx, same, same, too_few) == [0.5]


def test_a_short_track_is_confident_where_lane_order_anchors_its_link():
    # Track 0 has three detections; tracks 1 and 2 two each, detection 7 none. Detection 4's
    # link from 3 is anchored with a bonus, detection 6's from 5 by a chain that does not weigh.
    track = np.array([0, 0, 0, 1, 1, 2, 2, -1])
    predecessor = np.array([-1, -1, -1, -1, 3, -1, 5, -1])
    bonus = np.array([0.0, 0.0, 0.0, 0.0, 5.0, 0.0, 0.0, 0.0])
    assert confident_detections(track).tolist() == [0, 1, 2]
    assert confident_detections(track, Anchors(predecessor, bonus)).tolist() == [0, 1, 2, 3, 4]
    # An anchor the tracks did not follow makes nothing confident.
    apart = np.array([0, 0, 0, 1, 3, 2, 2, -1])
    assert confident_detections(apart, Anchors(predecessor, bonus)).tolist() == [0, 1, 2]


def test_segments_learned_span_by_span_are_those_learned_all_at_once(monkeypatch):
    # Many links are learned span by span, to hold one span's at a time (at 10^6 detections all
    # at once doubled the association's peak memory); each segment's numbers are its own, so
    # the model is the same to the last bit. Tracks with missed detections give spans 2 and 3.
    d = braking(1, n_vehicles=300)
    keep = np.random.default_rng(1).random(len(d)) > 0.2
    d = Detections.from_columns(
        d.position[keep], d.velocity[keep], d.timestamp[keep], target=d.target[keep].tolist()
    )
    params = AssignmentParams()
    s = arrange(d, params)
    _, truth = np.unique(d.target, return_inverse=True)
    prior = segment_prior(s, params.max_skip + 1, params)
    calls: list[list[int]] = []
    learn_spans = learning.learn_spans
    monkeypatch.setattr(
        learning, "learn_spans", lambda *args: calls.append(list(args[3])) or learn_spans(*args)
    )
    monkeypatch.setattr(learning, "SPANS_AT_ONCE_LINKS", 10**9)
    at_once = learn_segments(s, truth, params, prior)
    monkeypatch.setattr(learning, "SPANS_AT_ONCE_LINKS", 0)
    by_span = learn_segments(s, truth, params, prior)
    assert calls == [[1, 2, 3], [1], [2], [3]]
    for name in ("skew", "log_bias", "log_speed_ratio", "time_spread", "speed_spread"):
        np.testing.assert_array_equal(getattr(by_span, name), getattr(at_once, name), err_msg=name)
    assert (by_span.time_tails, by_span.speed_tails) == (at_once.time_tails, at_once.speed_tails)


def test_the_segments_of_a_sparse_sensor_keep_the_prior():
    # The sensor at 500 m keeps its first 15 reports of 150: its segments' links are those few,
    # all near the window's opening, where the matching pairs a vehicle with a neighbour's
    # partner (learned, a dying sensor's segment took a travel time 17-20 % short); the links
    # over it, made at the first round's loose spread, taught their span a travel time 8 %
    # short. Every span at, into, out of or over it keeps the prior's travel time; the segment
    # before it learns its own.
    d = sensor_cut(braking(2), 2, 15)
    params = AssignmentParams()
    s = arrange(d, params)
    assert s.sparse.tolist() == [False, False, True, False]
    _, truth = np.unique(d.target, return_inverse=True)
    prior = segment_prior(s, params.max_skip + 1, params)
    model = learn_segments(s, truth, params, prior)
    np.testing.assert_array_equal(model.log_bias[1:3, 1], prior.log_bias[1:3, 1])
    np.testing.assert_array_equal(model.log_bias[0:2, 2], prior.log_bias[0:2, 2])
    assert model.log_bias[0, 3] == prior.log_bias[0, 3]
    assert model.log_bias[0, 1] != prior.log_bias[0, 1]
