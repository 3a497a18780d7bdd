"""A link's cost (`assignment/costs.py`): -2 log densities of its residuals, lowest for the true
successor, and each term (travel time, speed change, the track's pace, a missed sensor) in it."""

from __future__ import annotations

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentParams, Tails
from roadlink.association.associators.assignment.costs import Level, affordable, link_cost
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.associators.assignment.tracks import detection_level
from roadlink.association.detections import Detections
from tests.association.associators.assignment.roads import (
    GAUSSIAN,
    kinematic_model,
    steady_vehicles,
)

PARAMS = AssignmentParams()


def every_link(d: Detections, params: AssignmentParams = PARAMS) -> tuple[np.ndarray, Pairs]:
    """The cost of every link from the first sensor's detections to the second's, each detection
    alone on either side (as the first linking round sees them)."""
    s = arrange(d, params)
    a, b = s.members(0), s.members(1)
    pairs = Pairs.between(
        s, kinematic_model(2, params), params, np.repeat(a, b.size), np.tile(b, a.size)
    )
    cost = link_cost(
        params,
        kinematic_model(2, params),
        pairs,
        detection_level(s, pairs.a),
        detection_level(s, pairs.b),
        s,
    )
    return cost.reshape(a.size, b.size), pairs


def test_the_true_successor_costs_least_on_two_sensors():
    # Five vehicles a second apart at 20-36 m/s past sensors 200 m apart: the fast ones overtake
    # the slow ones between the sensors, so order of arrival is no guide; speed and time are.
    starts, speeds = [0.0, 1.0, 2.0, 3.0, 4.0], [20.0, 24.0, 28.0, 32.0, 36.0]
    d = steady_vehicles(starts, speeds, [0.0, 200.0])
    cost, pairs = every_link(d)
    arrivals = [start + 200.0 / v for start, v in zip(starts, speeds, strict=True)]
    assert np.argsort(arrivals).tolist() != list(range(5))  # they did overtake
    label = d.target
    true = (label[pairs.a] == label[pairs.b]).reshape(cost.shape)
    assert np.all(cost[true] == pytest.approx(0.0, abs=1e-9))  # exact kinematics: no residual
    assert np.all(cost[~true] > 1.0)
    for row, truth in zip(cost, true, strict=True):
        assert np.argmin(row) == np.flatnonzero(truth)[0]


def test_a_change_of_speed_costs_by_its_weight():
    # One vehicle's departure at 20 m/s and two reports 5 s later at 100 m: one at 20 m/s, one
    # at 30 m/s. The travel time fits both, only the speed change tells them apart.
    d = Detections.from_columns([0.0, 100.0, 100.0], [20.0, 20.0, 30.0], [0.0, 5.0, 5.0])
    cost, _ = every_link(d)
    steady, changed = cost[0]
    assert changed > steady
    blind, _ = every_link(
        d, AssignmentParams(velocity_change_weight=0.0, preferred_speed_weight=0.0)
    )
    assert changed - steady > blind[0, 1] - blind[0, 0]


def test_a_track_far_from_the_pieces_pace_costs_more_and_long_means_count_up_to_a_memory():
    d = steady_vehicles([0.0], [20.0], [0.0, 100.0])
    s = arrange(d, PARAMS)
    model = kinematic_model(2, PARAMS)
    pairs = Pairs.between(s, model, PARAMS, np.array([0]), np.array([1]))

    def cost(before: float, count: float, params: AssignmentParams = PARAMS) -> float:
        after = Level(np.array([0.0]), np.array([1.0]))
        return float(
            link_cost(params, model, pairs, Level(np.array([before]), np.array([count])), after, s)[
                0
            ]
        )

    assert cost(0.0, 1.0) == pytest.approx(0.0, abs=1e-9)
    assert cost(0.3, 1.0) > cost(0.1, 1.0) > 0.0
    # A longer track's pace is surer, but only up to `preferred_speed_memory` detections.
    assert cost(0.3, 3.0) > cost(0.3, 1.0)
    assert cost(0.3, 30.0) == pytest.approx(cost(0.3, PARAMS.preferred_speed_memory))
    assert cost(0.3, 1.0, AssignmentParams(preferred_speed_weight=0.0)) == pytest.approx(
        0.0, abs=1e-9
    )


def test_each_missed_sensor_adds_the_miss_cost():
    d = steady_vehicles([0.0], [20.0], [0.0, 100.0, 200.0, 300.0])
    s = arrange(d, PARAMS)
    model = kinematic_model(4, PARAMS)
    a, b = np.array([0, 0, 0]), np.array([1, 2, 3])
    pairs = Pairs.between(s, model, PARAMS, a, b)
    cost = link_cost(PARAMS, model, pairs, detection_level(s, a), detection_level(s, b), s)
    np.testing.assert_allclose(cost, [0.0, PARAMS.miss_cost, 2 * PARAMS.miss_cost], atol=1e-9)


@pytest.mark.parametrize("tails", [GAUSSIAN, Tails(0.05, 4.0)])
@pytest.mark.parametrize("bonus", [0.0, 3.0])
def test_affordable_drops_only_links_whose_whole_cost_reaches_the_gate(tails, bonus):
    # Forty vehicles at 20-40 m/s half a second apart past two sensors: many links cost more than
    # the gate. Those `affordable` drops cost at least the gate with every term, less the bonus;
    # those it keeps are in their order, each with its own cost.
    rng = np.random.default_rng(3)
    starts, speeds = np.arange(40) * 0.5, rng.uniform(20.0, 40.0, 40)
    s = arrange(steady_vehicles(starts.tolist(), speeds.tolist(), [0.0, 300.0]), PARAMS)
    model = kinematic_model(2, PARAMS, tails=tails)
    a, b = s.members(0), s.members(1)
    pairs = Pairs.between(s, model, PARAMS, np.repeat(a, b.size), np.tile(b, a.size))
    whole = link_cost(
        PARAMS, model, pairs, detection_level(s, pairs.a), detection_level(s, pairs.b), s
    )
    kept = affordable(PARAMS, model, pairs, s, bonus)
    place = np.flatnonzero(np.isin(pairs.a * s.time.size + pairs.b, kept.a * s.time.size + kept.b))
    assert 0 < place.size < pairs.a.size
    assert np.array_equal(kept.a, pairs.a[place]) and np.array_equal(kept.b, pairs.b[place])
    assert kept.own is not None
    assert np.array_equal(kept.own, pairs.own_cost(model, PARAMS)[place])
    dropped = np.setdiff1d(np.arange(pairs.a.size), place)
    assert np.all(whole[dropped] - bonus >= PARAMS.gate_cost)
    assert np.any(whole[place] - bonus < PARAMS.gate_cost)
