"""The naive references of the accuracy benchmarks: what they do, checked on data where the answer
is known."""

from __future__ import annotations

import numpy as np

from benchmarks.references import chain_groups, fifo_groups
from roadlink.association.detections import Detections
from roadlink.association.scores import score_grouping
from roadlink.simulation import preset, simulate


def _convoy(n: int, speeds: list[float]) -> Detections:
    """`n` vehicles, 3 s apart, at constant `speeds[k % len(speeds)]`, past sensors every 100 m."""
    sensors = np.arange(0.0, 500.0, 100.0)
    vehicle = np.repeat(np.arange(n), sensors.size)
    position = np.tile(sensors, n)
    speed = np.array([speeds[k % len(speeds)] for k in vehicle])
    return Detections.from_columns(
        position,
        speed,
        3.0 * vehicle + position / speed,
        target=[f"v{k}" for k in vehicle],
    )


def test_fifo_is_exact_when_nobody_overtakes_and_wrong_when_they_do():
    in_order = _convoy(20, [20.0])
    assert score_grouping(fifo_groups(in_order), in_order.target).accuracy == 1.0
    overtaking = _convoy(20, [10.0, 40.0])  # fast ones pass the slow one ahead of them
    assert score_grouping(fifo_groups(overtaking), overtaking.target).accuracy < 0.6


def test_chain_follows_speeds_through_overtaking():
    overtaking = _convoy(20, [10.0, 40.0])
    assert score_grouping(chain_groups(overtaking), overtaking.target).accuracy == 1.0


def test_chain_scores_as_a_kinematic_matcher_does_on_the_papers_data():
    accuracies = []
    for seed in range(5):
        d = simulate(preset("large"), seed=seed).detections
        accuracies.append(score_grouping(chain_groups(d.without_labels()), d.target).accuracy)
    assert np.mean(accuracies) > 0.9
