"""benchmarks/lane_order.py: aligning each lane in order, on a queue built to keep lane order."""

from __future__ import annotations

import numpy as np
import pytest

from benchmarks.lane_order import (
    lane_order_successors,
    measure,
    monotone_alignment,
    segment_link_accuracy,
    successors_of,
)
from roadlink.association.detections import Detections
from tests.helpers import lane_queue


def test_an_alignment_keeps_order_and_pairs_only_what_is_likelier_the_same() -> None:
    # Row i is the vehicle of column i + 2: cost -1 there, +1 elsewhere (never worth a pair).
    cost = np.ones((5, 7))
    for i in range(5):
        cost[i, i + 2] = -1.0
    cost[4, 0] = -3.0  # a good pair out of order: taking it would lose four in order
    assert monotone_alignment(cost) == [(i, i + 2) for i in range(5)]
    assert monotone_alignment(np.ones((3, 3))) == []


def test_lane_order_against_true_curves_recovers_a_lane_keeping_queue() -> None:
    d = lane_queue()
    sensor = np.searchsorted(np.unique(d.position), d.position)
    labels = np.unique(d.target.astype(str), return_inverse=True)[1]
    truth = successors_of(labels, sensor)
    given_curves = segment_link_accuracy(lane_order_successors(d, sensor, truth), truth, sensor)
    # Travel times of 40-80 s are 10-25 headways long, yet keeping each lane's order with the
    # true curves recovers nearly every link.
    assert min(given_curves) >= 0.95


def test_measure_reports_every_method_and_refuses_cases_without_lanes() -> None:
    d = lane_queue(seed=1)
    report = measure(d)
    assert set(report) == {
        "assignment, no lane anchors",
        "assignment",
        "lane order, true curves",
    }
    for method in report.values():
        assert 0.0 <= method.accuracy <= 1.0
        assert len(method.segment_links) == 2
    assert report["assignment"].accuracy > report["assignment, no lane anchors"].accuracy
    blind = Detections.from_columns(d.position, d.velocity, d.timestamp, target=d.target)
    with pytest.raises(SystemExit, match="lane and length"):
        measure(blind)
