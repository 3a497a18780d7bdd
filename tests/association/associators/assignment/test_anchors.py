"""assignment/anchors.py: lane-order anchors, and what they do for `assignment` in a queue."""

from __future__ import annotations

import numpy as np

from roadlink.association import associate
from roadlink.association.associators.assignment.anchors import (
    ANCHOR_BONUS,
    JUMP,
    lane_order_anchors,
    smooth_chain,
    weigh_anchors,
)
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.detections import Detections
from tests.helpers import lane_queue


def chain_case(offset: int, n: int = 30) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row i is the vehicle of column i + offset; every travel time is 60 s, slowly drifting,
    and the columns are 3 s apart; each pair's gain is weakly positive for the true pair."""
    rng = np.random.default_rng(offset)
    up = np.cumsum(np.full(n, 3.0))
    passed = np.concatenate([np.arange(-offset, 0) * 3.0, up])  # earlier vehicles first
    down = passed + 60.0 + 0.01 * passed
    travel = down[None, :] - up[:, None]
    with np.errstate(invalid="ignore"):
        log_travel = np.where(travel > 0, np.log(np.maximum(travel, 1e-9)), np.nan)
    gain = rng.normal(-1.0, 1.0, travel.shape)
    gain[np.arange(n), np.arange(n) + offset] = 1.0
    gain = np.where(travel > 0, gain, -np.inf)
    return gain, log_travel, np.full_like(log_travel, np.nan)


def test_the_chain_follows_the_smooth_alignment_not_the_best_single_pairs() -> None:
    gain, log_travel, kinematic = chain_case(offset=4)
    # A pair shifted by one vehicle that fits better on its own than the true one.
    gain[10, 13] = 5.0
    pairs = smooth_chain(gain, log_travel, kinematic)
    assert pairs == [(i, i + 4) for i in range(30)]


def test_the_chain_keeps_order_and_makes_nothing_of_nothing() -> None:
    gain, log_travel, kinematic = chain_case(offset=2)
    pairs = smooth_chain(gain, log_travel, kinematic)
    rows, columns = zip(*pairs, strict=True)
    assert list(rows) == sorted(rows) and list(columns) == sorted(columns)
    assert smooth_chain(np.full((4, 4), -np.inf), log_travel[:4, :4], kinematic[:4, :4]) == []
    # Pairs that gain nothing are not worth a chain.
    assert smooth_chain(np.full((5, 5), -JUMP), log_travel[:5, :5], kinematic[:5, :5]) == []


def test_anchors_in_a_lane_keeping_queue_are_right_and_cover_most_vehicles() -> None:
    d = lane_queue()
    params = AssignmentParams()
    s = arrange(d, params)
    anchor = lane_order_anchors(s, segment_prior(s, params.max_skip + 1, params).features)
    anchored = np.flatnonzero(anchor >= 0)
    labels = d.target.astype(str)
    assert np.mean(labels[anchor[anchored]] == labels[anchored]) >= 0.98
    # Detections at the second and third sensor whose vehicle the sensor before saw.
    seen_before = {(label, position) for label, position in zip(labels, d.position, strict=True)}
    linkable = [
        i
        for i in range(len(d))
        if d.position[i] > 0 and (labels[i], d.position[i] - 200.0) in seen_before
    ]
    assert anchored.size >= 0.9 * len(linkable)


def test_a_segment_earns_its_bonus_by_how_often_the_tracks_contradict_its_anchors() -> None:
    d = lane_queue()
    s = arrange(d, AssignmentParams())
    labels = np.unique(d.target.astype(str), return_inverse=True)[1]
    # Every detection of sensor k + 1 anchored to its true predecessor at sensor k.
    predecessor = np.full(len(d), -1, dtype=np.int64)
    for i in range(len(d)):
        before = np.flatnonzero((labels == labels[i]) & (s.sensor == s.sensor[i] - 1))
        if before.size:
            predecessor[i] = before[0]
    agreeing = labels.copy()  # tracks that link exactly as the anchors do
    lost = agreeing.copy()
    second = np.flatnonzero(s.sensor == 2)
    lost[second] = np.roll(lost[second], 1)  # tracks shifted by a vehicle into the last sensor
    calm = weigh_anchors(s, predecessor, agreeing)
    assert (calm.bonus == 0.0).all()
    shaken = weigh_anchors(s, predecessor, lost)
    into_last = (predecessor >= 0) & (s.sensor == 2)
    assert np.allclose(shaken.bonus[into_last], ANCHOR_BONUS)
    assert (shaken.bonus[~into_last] == 0.0).all()


def test_no_anchors_without_lanes_and_lengths() -> None:
    d = lane_queue()
    blind = Detections.from_columns(d.position, d.velocity, d.timestamp, target=d.target)
    params = AssignmentParams()
    s = arrange(blind, params)
    assert (lane_order_anchors(s, None) < 0).all()


def test_anchors_lift_assignment_in_a_queue() -> None:
    d = lane_queue(seed=2)
    anchored = associate(d, "assignment").metrics
    alone = associate(d, "assignment", {"lane_anchors": False}).metrics
    assert anchored is not None and alone is not None
    # Travel times 10-25 headways long: speeds and times alone cannot tell neighbours apart.
    assert anchored.accuracy >= 0.95
    assert anchored.accuracy > alone.accuracy + 0.05
