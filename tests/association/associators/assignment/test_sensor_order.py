"""Two sensors whose positions are swapped (`assignment/sensor_order.py`): found where the
segments round them keep time once their detections are exchanged, taken the other way round,
and named; never on the committed cases as placed, nor in queues."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.clocks import Lag, clock_offsets
from roadlink.association.associators.assignment.sensor_order import (
    in_road_order,
    keeps_time,
    order_warnings,
    swapped_pairs,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate

DATA = Path(__file__).parents[3] / "data"
COMMITTED = sorted([*DATA.glob("sumo/*.csv"), *DATA.glob("sumo-features/*.csv")])


def swapped(d: Detections, k: int) -> Detections:
    """`d` as a deployment reports it that gives sensors k and k + 1 each other's position."""
    positions = np.unique(d.position)
    a, b = positions[k], positions[k + 1]
    return dataclasses.replace(
        d, position=np.where(d.position == a, b, np.where(d.position == b, a, d.position))
    )


def pairs_of(d: Detections) -> tuple[int, ...]:
    return arrange(d.without_labels(), AssignmentParams()).swapped


@pytest.mark.parametrize("path", COMMITTED, ids=lambda p: f"{p.parent.name}/{p.stem}")
def test_sensors_as_placed_are_never_taken_the_other_way_round(path):
    assert pairs_of(read_detections_csv(path)) == ()


@pytest.mark.parametrize("case", ["sumo-freeflow", "sumo-dense", "sumo-junctions"])
@pytest.mark.parametrize("k", [0, 4, 9])
def test_a_swapped_pair_anywhere_on_a_flowing_road_is_found(case, k):
    assert pairs_of(swapped(read_detections_csv(DATA / "sumo" / f"{case}.csv"), k)) == (k,)


@pytest.mark.parametrize("case", ["sumo-stopgo", "sumo-queue"])
def test_in_a_queue_no_pair_is_taken_for_swapped(case):
    """Queued segments keep no time either way round: nothing is exchanged."""
    assert pairs_of(swapped(read_detections_csv(DATA / "sumo" / f"{case}.csv"), 4)) == ()


@pytest.mark.parametrize(("case", "before"), [("sumo-freeflow", 0.614), ("sumo-dense", 0.668)])
def test_traffic_past_a_swapped_pair_is_grouped_as_placed_and_the_pair_named(case, before):
    # `before`: the accuracy as the swapped positions were taken, without a word.
    placed = read_detections_csv(DATA / "sumo" / f"{case}.csv")
    result = associate(swapped(placed, 4))
    expected = associate(placed)
    assert result.metrics is not None and expected.metrics is not None
    assert result.metrics.accuracy == expected.metrics.accuracy > before + 0.25
    positions = np.unique(placed.position)
    assert any(
        f"positions {positions[4]:g} and {positions[5]:g}" in warning for warning in result.warnings
    )
    # The result gives every detection where it was reported.
    np.testing.assert_array_equal(result.detections.position, swapped(placed, 4).position)


def test_a_paper_size_batch_is_not_tested():
    assert pairs_of(swapped(simulate(preset("large"), seed=0).detections, 2)) == ()


def test_a_segment_keeps_time_within_a_quarter_of_its_travel_time_and_a_bin():
    assert keeps_time(Lag(2.9, 10.0, 0.5, 10.0))
    assert keeps_time(Lag(-2.9, 10.0, 0.5, 10.0))
    assert not keeps_time(Lag(3.1, 10.0, 0.5, 10.0))
    assert not keeps_time(None)


def test_a_pairs_detections_are_exchanged_and_named():
    sensor = np.array([0, 1, 2, 3, 4, 1, 2])
    np.testing.assert_array_equal(in_road_order(sensor, [1]), [0, 2, 1, 3, 4, 2, 1])
    np.testing.assert_array_equal(in_road_order(sensor, [0, 3]), [1, 0, 2, 4, 3, 0, 2])
    assert in_road_order(sensor, []) is sensor
    (warning,) = order_warnings(np.array([0.0, 250.0, 500.0]), (1,))
    assert "positions 250 and 500" in warning and "swapped" in warning
    two = swapped_pairs(np.array([0.0, 100.0]), [np.zeros(60)] * 2, [np.ones(60)] * 2)
    assert two == ([], None)


def test_the_lags_of_the_order_as_reported_serve_the_clocks_too():
    """The clocks' search starts from the lags the order's test measured, where no pair was
    exchanged and no clock is far off: the same lags, so the same offsets (here the middle
    sensor of the committed dense traffic 20 s late, set right) as measured afresh."""
    d = read_detections_csv(DATA / "sumo" / "sumo-dense.csv")
    middle = np.unique(d.position)[5]
    late = dataclasses.replace(d, timestamp=d.timestamp + 20.0 * (d.position == middle))
    positions, sensor = np.unique(late.position, return_inverse=True)
    order = np.lexsort((late.timestamp, sensor))
    start = np.searchsorted(sensor[order], np.arange(positions.size + 1))
    times = [late.timestamp[order[start[k] : start[k + 1]]] for k in range(positions.size)]
    speeds = [late.velocity[order[start[k] : start[k + 1]]] for k in range(positions.size)]
    pairs, lags = swapped_pairs(positions, times, speeds)
    assert pairs == [] and lags is not None and len(lags) == positions.size - 1
    sorted_time, sorted_speed = late.timestamp[order], late.velocity[order]
    shared = clock_offsets(positions, sorted_time, sorted_speed, start, lags)
    afresh = clock_offsets(positions, sorted_time, sorted_speed, start)
    assert shared.tolist() == afresh.tolist()
    assert shared[5] == pytest.approx(20.0, abs=0.5)
