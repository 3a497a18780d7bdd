"""Gating (`assignment/gating.py`): which candidate links a gate in time lets through, and what
their cost needs (the standardised travel-time error, the speed change, the span)."""

from __future__ import annotations

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentParams, Tails, gating
from roadlink.association.associators.assignment.gating import (
    EverySensor,
    Gate,
    Pairs,
    _arrivals_between,
    gated_pairs,
    time_residual,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.detections import Detections
from tests.association.associators.assignment.roads import kinematic_model

PARAMS = AssignmentParams()


def one_departure(arrivals: list[float], speed: float = 20.0) -> Detections:
    """Row 0: a vehicle at 20 m/s passes the sensor at 0 m at t = 0; rows 1...: reports at the
    sensor 100 m on, at `arrivals` (the vehicle's own arrives at t = 5), all at `speed`."""
    return Detections.from_columns(
        position=[0.0] + [100.0] * len(arrivals),
        velocity=[20.0] + [speed] * len(arrivals),
        timestamp=[0.0, *arrivals],
    )


def gated(d: Detections, gate: float = PARAMS.gate_cost, tails: Tails | None = None) -> Pairs:
    s = arrange(d, PARAMS)
    model = kinematic_model(s.positions.size, PARAMS, **({} if tails is None else {"tails": tails}))
    return gated_pairs(s, model, PARAMS, np.array([0]), 1, gate)


def test_the_gate_keeps_the_links_inside_its_window_and_rejects_those_outside():
    # Arrivals 5 s (on time), 5.3 s (0.6 spreads late), 9 s (8 spreads late: 64 > 18) and 50 s.
    pairs = gated(one_departure([5.0, 5.3, 9.0, 50.0]))
    assert sorted(pairs.b.tolist()) == [1, 2]
    assert pairs.a.tolist() == [0, 0] and pairs.span.tolist() == [1, 1]
    on_time = pairs.r_time[pairs.b == 1][0]
    late = pairs.r_time[pairs.b == 2][0]
    assert on_time == pytest.approx(0.0, abs=1e-12) and 0.0 < late < 1.0


def test_the_gated_pairs_carry_what_the_same_links_cost_between_any_sensors():
    d = one_departure([4.8, 5.0, 5.3])
    s = arrange(d, PARAMS)
    model = kinematic_model(2, PARAMS)
    pairs = gated_pairs(s, model, PARAMS, np.array([0]), 1, PARAMS.gate_cost)
    direct = Pairs.between(s, model, PARAMS, pairs.a, pairs.b)
    for name in ("r_time", "ratio", "speed_spread", "span"):
        np.testing.assert_allclose(getattr(pairs, name), getattr(direct, name), rtol=1e-12)


def test_heavy_tails_widen_the_gate_but_no_link_outruns_the_fastest_speed_measured():
    # In heavy tails a travel time 8 spreads off is within the gate; the report 0.5 s after
    # departure is not, however cheap its residual: 100 m in 0.5 s is 200 m/s, past 1.5 times
    # the fastest speed (20 m/s) either sensor measured.
    heavy = Tails(0.5, 30.0)
    assert heavy.cost(np.array([-9.0]))[0] < PARAMS.gate_cost
    pairs = gated(one_departure([0.5, 5.0, 9.0]), tails=heavy)
    assert sorted(pairs.b.tolist()) == [2, 3]


def test_a_link_over_a_missed_sensor_pays_the_miss_cost_within_the_gate():
    # A vehicle at 20 m/s seen at 0 m and at 200 m (t = 10), not at 100 m.
    d = Detections.from_columns([0.0, 100.0, 200.0], [20.0, 20.0, 20.0], [0.0, 50.0, 10.0])
    s = arrange(d, PARAMS)
    model = kinematic_model(3, PARAMS)
    skip = PARAMS.miss_cost  # the link's whole cost: its residuals are 0
    assert gated_pairs(s, model, PARAMS, np.array([0]), 2, skip).b.size == 0
    kept = gated_pairs(s, model, PARAMS, np.array([0]), 2, skip + 0.01)
    assert kept.b.tolist() == [2] and kept.span.tolist() == [2]


def test_nothing_to_link_from_or_to_gates_nothing():
    d = one_departure([5.0])
    s = arrange(d, PARAMS)
    model = kinematic_model(2, PARAMS)
    empty = np.zeros(0, dtype=np.int64)
    assert gated_pairs(s, model, PARAMS, empty, 1, PARAMS.gate_cost).a.size == 0
    # A departure after every arrival at the next sensor links to none of them.
    late = Detections.from_columns([0.0, 100.0], [20.0, 20.0], [100.0, 5.0])
    s = arrange(late, PARAMS)
    assert gated_pairs(s, model, PARAMS, np.array([0]), 1, PARAMS.gate_cost).a.size == 0


def test_the_time_residual_is_standardised_and_widened_by_an_unexplained_speed_change():
    params = AssignmentParams(travel_time_spread=0.1, timestamp_noise=0.0)
    predicted, spread = np.array([10.0]), np.array([0.1])
    on_time, _ = time_residual(params, predicted, np.array([10.0]), np.array([0.0]), spread)
    late, ratio = time_residual(params, predicted, np.array([11.0]), np.array([0.0]), spread)
    assert on_time[0] == 0.0 and late[0] == pytest.approx(1.0) and ratio[0] == 0.0
    # The same second late, when the speed changed by log 0.5 somewhere on the way: less sure.
    changed, _ = time_residual(params, predicted, np.array([11.0]), np.array([0.5]), spread)
    assert 0.0 < changed[0] < late[0]
    # The clocks' noise adds to every spread, however short the travel time.
    noisy = AssignmentParams(timestamp_noise=0.5)
    tiny, _ = time_residual(noisy, np.array([0.01]), np.array([1.01]), np.zeros(1), spread)
    assert tiny[0] == pytest.approx(1.0 / np.sqrt(0.001**2 + 2 * 0.5**2))


def test_pairs_are_taken_and_concatenated_field_by_field():
    d = one_departure([5.0, 5.3])
    s = arrange(d, PARAMS)
    pairs = Pairs.between(s, kinematic_model(2, PARAMS), PARAMS, np.array([0, 0]), np.array([1, 2]))
    second = pairs.take(np.array([False, True]))
    assert second.b.tolist() == [2] and second.r_time[0] == pairs.r_time[1]
    both = Pairs.concatenate([second, pairs.take(np.array([True, False]))])
    assert both.b.tolist() == [2, 1] and both.span.tolist() == [1, 1]
    assert Pairs.none().a.size == Pairs.none().r_time.size == 0
    # Their own costs, worked out once, go with them, and are what each would cost alone.
    model = kinematic_model(2, PARAMS)
    alone = [pairs.take(np.array([i])).own_cost(model, PARAMS)[0] for i in (0, 1)]
    pairs.own = pairs.own_cost(model, PARAMS)
    assert pairs.own.tolist() == alone
    assert pairs.take(np.array([1])).own.tolist() == [pairs.own[1]]
    assert Pairs.concatenate([pairs, pairs]).own.tolist() == 2 * pairs.own.tolist()
    assert Pairs.concatenate([pairs, second]).own is None  # not every part has them


def three_sensors(rng: np.random.Generator, n: int) -> Detections:
    """n reports at each of three sensors, at random speeds and times."""
    return Detections.from_columns(
        position=np.repeat([0.0, 100.0, 250.0], n),
        velocity=rng.uniform(15.0, 35.0, 3 * n),
        timestamp=np.concatenate([rng.uniform(0.0, 200.0, n) + 8.0 * k for k in range(3)]),
    )


def test_gating_among_some_arrivals_is_gating_all_then_keeping_those():
    rng = np.random.default_rng(3)
    n = 400
    s = arrange(three_sensors(rng, n), PARAMS)
    model = kinematic_model(3, PARAMS, tails=Tails(0.05, 4.0))
    among = rng.random(3 * n) < 0.3
    for q, a in ((1, s.members(0)), (2, np.concatenate([s.members(1), s.members(0)]))):
        every = gated_pairs(s, model, PARAMS, a, q, 2.0 * PARAMS.gate_cost)
        some = gated_pairs(s, model, PARAMS, a, q, 2.0 * PARAMS.gate_cost, among=among)
        expected = every.take(among[every.b])
        assert 0 < some.a.size < every.a.size
        for name in ("a", "b", "r_time", "ratio", "speed_spread", "span"):
            assert np.array_equal(getattr(some, name), getattr(expected, name))
    none = np.zeros(3 * n, dtype=bool)
    assert gated_pairs(s, model, PARAMS, s.members(0), 1, PARAMS.gate_cost, among=none).a.size == 0


@pytest.mark.parametrize("among", [False, True])
def test_every_sensors_links_gated_at_once_are_those_gated_sensor_by_sensor(among: bool):
    # To the last bit, in the same order, whatever the departures' order.
    rng = np.random.default_rng(5)
    s = arrange(three_sensors(rng, 60), PARAMS)
    model = kinematic_model(3, PARAMS, tails=Tails(0.05, 4.0))
    arrivals = rng.random(180) < 0.5 if among else None
    every = EverySensor.gate(s, model, PARAMS, 2.0 * PARAMS.gate_cost)
    for q, a in ((1, s.members(0)), (2, rng.permutation(np.r_[s.members(1), s.members(0)]))):
        one = gated_pairs(s, model, PARAMS, a, q, 2.0 * PARAMS.gate_cost, among=arrivals)
        at_once = every.into(q, a, arrivals)
        assert one.a.size > 0
        for name in ("a", "b", "r_time", "ratio", "speed_spread", "span"):
            assert np.array_equal(getattr(at_once, name), getattr(one, name))


def test_the_links_across_a_boundary_gated_at_once_are_those_gated_sensor_by_sensor():
    # To the last bit, in the same order: the run of every sensor's links filtered (a paper-size
    # batch) against each sensor's links gated from the tails within its reach.
    rng = np.random.default_rng(7)
    s = arrange(three_sensors(rng, 15), PARAMS)
    model = kinematic_model(3, PARAMS, tails=Tails(0.05, 4.0))
    at_once = Gate.of(s, model, PARAMS, 2.0 * PARAMS.gate_cost)
    one_by_one = Gate(s, model, PARAMS, 2.0 * PARAMS.gate_cost)
    assert at_once.every is not None
    heads = rng.random(45) < 0.7
    for k in (1, 2):
        tails = s.order[: s.start[k]][rng.random(int(s.start[k])) < 0.6]
        expected = one_by_one.across(k, tails, heads)
        found = at_once.across(k, tails, heads)
        assert expected.a.size > 0
        for name in ("a", "b", "r_time", "ratio", "speed_spread", "span"):
            assert np.array_equal(getattr(found, name), getattr(expected, name))


@pytest.mark.parametrize("nan", [False, True])
def test_the_arrivals_within_every_window_at_once_are_each_sensors_own_searchsorted(nan: bool):
    # Windows whose ends fall on arrival times: the left end keeps them, the right end too; and
    # ends that are NaN or infinite (NaN: one stable sort instead of the binary searches).
    rng = np.random.default_rng(8)
    s = arrange(three_sensors(rng, 30), PARAMS)
    s.sorted_time[:] = np.round(s.sorted_time)  # ties, and ends on them
    for k in range(3):
        s.sorted_time[s.start[k] : s.start[k + 1]].sort()
    q = rng.integers(1, 3, 50)
    lo = np.round(rng.uniform(0.0, 220.0, 50))
    hi = lo + rng.integers(-2, 20, 50)
    lo[:3], hi[3:6] = -np.inf, np.inf
    if nan:
        lo[10], hi[11], lo[12], hi[12] = np.nan, np.nan, np.nan, np.nan
    first, count = _arrivals_between(s, q, lo, hi)
    for i in range(50):
        times = s.sorted_time[s.start[q[i]] : s.start[q[i] + 1]]
        start = np.searchsorted(times, lo[i], side="left")
        assert first[i] == s.start[q[i]] + start
        assert count[i] == max(np.searchsorted(times, hi[i], side="right") - start, 0)


@pytest.mark.parametrize("among", [False, True])
def test_links_gated_chunk_by_chunk_are_those_gated_at_once(
    among: bool, monkeypatch: pytest.MonkeyPatch
):
    # To the last bit, in the same order: chunks of a few candidates, and of one departure's.
    rng = np.random.default_rng(6)
    s = arrange(three_sensors(rng, 300), PARAMS)
    model = kinematic_model(3, PARAMS, tails=Tails(0.05, 4.0))
    arrivals = rng.random(900) < 0.5 if among else None
    a = rng.permutation(np.r_[s.members(1), s.members(0)])
    whole = gated_pairs(s, model, PARAMS, a, 2, 2.0 * PARAMS.gate_cost, among=arrivals)
    for chunk in (1, 7, 100):
        monkeypatch.setattr(gating, "GATE_CHUNK", chunk)
        chunked = gated_pairs(s, model, PARAMS, a, 2, 2.0 * PARAMS.gate_cost, among=arrivals)
        assert whole.a.size > 100
        for name in ("a", "b", "r_time", "ratio", "speed_spread", "span"):
            assert np.array_equal(getattr(chunked, name), getattr(whole, name))


def test_a_narrower_gate_picked_from_a_wider_ones_links_is_that_gate_at_once():
    # To the last bit, in the same order, each link's own cost too: what a forward pass takes
    # from the re-pairing sweep's gating (its gate is REFINE_GATE_FACTOR times the pass's).
    rng = np.random.default_rng(9)
    s = arrange(three_sensors(rng, 15), PARAMS)
    model = kinematic_model(3, PARAMS, tails=Tails(0.05, 4.0))
    wide = Gate.of(s, model, PARAMS, 2.0 * PARAMS.gate_cost)
    assert wide.every is not None
    for gate in (PARAMS.gate_cost, 0.3 * PARAMS.gate_cost):
        narrow, direct = wide.narrowed(gate), Gate.of(s, model, PARAMS, gate)
        assert narrow.every is not None and direct.every is not None
        assert narrow.gate == gate
        assert 0 < direct.every.pairs.a.size < wide.every.pairs.a.size
        assert np.array_equal(narrow.every.bounds, direct.every.bounds)
        for name in ("a", "b", "r_time", "ratio", "speed_spread", "span", "own"):
            assert np.array_equal(
                getattr(narrow.every.pairs, name), getattr(direct.every.pairs, name)
            )


def test_a_narrower_gate_of_a_gating_sensor_by_sensor_gates_sensor_by_sensor():
    rng = np.random.default_rng(10)
    s = arrange(three_sensors(rng, 60), PARAMS)
    model = kinematic_model(3, PARAMS)
    wide = Gate.of(s, model, PARAMS, 2.0 * PARAMS.gate_cost)
    assert wide.every is None
    narrow = wide.narrowed(PARAMS.gate_cost)
    assert narrow.every is None and narrow.gate == PARAMS.gate_cost
