"""Tracks from links (`assignment/tracks.py`): the sequential pass, and a track's chain of
detections read both ways."""

import numpy as np
import pytest

from roadlink.association.associators.assignment import (
    AssignmentAssociator,
    AssignmentParams,
    tracks,
)
from roadlink.association.associators.assignment.duplicates import duplicate_followers
from roadlink.association.associators.assignment.edges import WindowEdges
from roadlink.association.associators.assignment.ends import RoadEnds
from roadlink.association.associators.assignment.gating import Gate
from roadlink.association.associators.assignment.learning import learn_segments
from roadlink.association.associators.assignment.matching import match
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import REFINE_GATE_FACTOR
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.refine import refine_boundaries
from roadlink.association.associators.assignment.sensors import Sensors, arrange
from roadlink.association.associators.assignment.tracks import (
    Foreseen,
    LevelRelay,
    SweepSetup,
    build_tracks,
    successors,
    tracks_from_links,
)
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate


def three_sensors() -> Detections:
    # Two vehicles (a: rows 0, 2, 4; b: rows 1, 3, 5) past sensors at 0, 100 and 200 m.
    return Detections.from_columns(
        position=[0.0, 0.0, 100.0, 100.0, 200.0, 200.0],
        velocity=[20.0, 25.0, 20.0, 25.0, 20.0, 25.0],
        timestamp=[0.0, 1.0, 5.0, 5.0, 10.0, 9.0],
    )


def test_successors_follow_each_track_in_road_order():
    s = arrange(three_sensors(), AssignmentParams())
    track = np.array([0, 1, 0, 1, 0, -1])
    nxt, prv = successors(s, track)
    assert nxt.tolist() == [2, 3, 4, -1, -1, -1]
    assert prv.tolist() == [-1, -1, 0, 1, 2, -1]


def test_tracks_from_links_number_the_chains_and_leave_the_rest_out():
    s = arrange(three_sensors(), AssignmentParams())
    prv = np.array([-1, -1, 0, 1, 2, 3])
    in_track = np.array([True, True, True, True, True, False])
    assert tracks_from_links(s, prv, in_track).tolist() == [0, 1, 0, 1, 0, -1]
    # Read back, the links are what they were built from.
    nxt, back = successors(s, tracks_from_links(s, prv, np.ones(6, dtype=bool)))
    assert back.tolist() == prv.tolist() and nxt.tolist() == [2, 3, 4, 5, -1, -1]


def test_a_pass_that_works_out_the_sweeps_gating_builds_the_same_tracks_and_hands_it_over():
    # A paper-size batch (every sensor's links gated at once): the pass takes its gating and
    # edges from the sweep's, at its narrower gate, and the sweep finds them ready for this
    # model alone; tracks, re-paired tracks and confidences are those worked out apart.
    params = AssignmentParams()
    s = arrange(simulate(preset("large"), seed=1).detections, params)
    model = segment_prior(s, params.max_skip + 1, params)
    leader = duplicate_followers(s, params)
    setup = SweepSetup()
    plain = build_tracks(s, model, params, leader, None, 0.0, 1.0)
    shared = build_tracks(s, model, params, leader, None, 0.0, 1.0, sweep=setup)
    assert np.array_equal(plain, shared) and (plain >= 0).sum() > 50
    wide = REFINE_GATE_FACTOR * params.gate_cost
    ready = setup.of(model, wide)
    assert ready is not None and ready[0].every is not None
    assert setup.of(model.copy(), wide) is None and setup.of(model, params.gate_cost) is None
    confidence = [np.full(s.time.size, np.nan) for _ in range(2)]
    apart = refine_boundaries(s, model, params, plain.copy(), confidence[0])
    together = refine_boundaries(s, model, params, plain.copy(), confidence[1], setup=setup)
    assert np.array_equal(apart[0], together[0]) and apart[1] == together[1]
    assert np.array_equal(confidence[0], confidence[1], equal_nan=True)


FAULTS = {"miss_probability": 0.1, "false_alarm_rate": 0.02, "duplicate_probability": 0.05}
FEATURES = {"lanes": 3, "vehicle_lengths": True, "length_noise": 0.05, "velocity_noise": 0.03}


def second_round(
    traffic: dict[str, object], seed: int, relay: LevelRelay | None = None
) -> tuple[AssignmentParams, Sensors, np.ndarray, np.ndarray, SegmentModel]:
    """A paper-size batch, its first round's tracks (leaving their levels in `relay`) and the
    model learned from them: the parameters, sensors, leaders, tracks and model."""
    params = AssignmentParams()
    s = arrange(simulate(preset("medium", **traffic), seed=seed).detections, params)
    prior = segment_prior(s, params.max_skip + 1, params)
    leader = duplicate_followers(s, params)
    first = build_tracks(s, prior, params, leader, None, 0.0, 1.0, relay=relay)
    return params, s, leader, first, learn_segments(s, first, params, prior)


@pytest.mark.parametrize("traffic", [{}, FAULTS, FEATURES])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_pass_that_foresees_tracks_builds_what_it_builds_without(
    traffic: dict[str, object], seed: int
) -> None:
    # Paper-size batches, the second round's pass: foreseeing the first round's tracks, its
    # own, or its own cut at one sensor (the pass goes on sensor by sensor from there, or from
    # the start), it builds the tracks it builds alone.
    params, s, leader, first, model = second_round(traffic, seed)
    plain = build_tracks(s, model, params, leader, None, 0.0, 1.0)
    cut = plain.copy()
    for sensor in (1, s.positions.size // 2, s.positions.size - 1):
        late = (s.sensor >= sensor) & (cut == cut[s.members(sensor)[0]])
        cut[late] = cut.max() + 1
    for expected in (first, plain, cut, np.full_like(plain, -1)):
        foreseeing = build_tracks(s, model, params, leader, None, 0.0, 1.0, expected=expected)
        assert np.array_equal(foreseeing, plain)
    # Every sensor's matching solved (none taken as surely the expected tracks'): the same.
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(tracks, "sure_matchings", lambda *args: np.zeros(99, dtype=bool))
        for expected in (first, plain, cut):
            solved = build_tracks(s, model, params, leader, None, 0.0, 1.0, expected=expected)
            assert np.array_equal(solved, plain)


@pytest.mark.parametrize("traffic", [{}, FAULTS, FEATURES])
@pytest.mark.parametrize("seed", [0, 1])
def test_a_pass_foresees_with_the_levels_the_pass_before_left_the_costs_it_works_out(
    traffic: dict[str, object], seed: int
) -> None:
    # The second round's pass, foreseeing the first round's tracks: with the levels the first
    # pass left (`LevelRelay`; its pace worked out again with the learned model) or extended
    # sensor by sensor, every candidate's cost is the same to the bit.
    relay = LevelRelay()
    params, s, _, first, model = second_round(traffic, seed, relay)
    assert relay.track is first and relay.level is not None
    gate = Gate.of(s, model, params, params.gate_cost)
    edges = WindowEdges.of(s, model, params.gate_cost / 2.0)
    assert gate.every is not None
    relayed = Foreseen.of(s, model, params, gate.every, edges, None, first, relay)
    extended = Foreseen.of(s, model, params, gate.every, edges, None, first)
    assert relayed.cost.size > 50 and np.array_equal(relayed.cost, extended.cost)
    # Not the tracks the relay holds: the levels are extended anew.
    other = Foreseen.of(s, model, params, gate.every, edges, None, first.copy(), relay)
    assert np.array_equal(other.cost, extended.cost)


@pytest.mark.parametrize("traffic", [{}, FAULTS, FEATURES])
@pytest.mark.parametrize(
    ("name", "seed"), [("medium", 0), ("medium", 1), ("small", 2), ("congested", 0)]
)
def test_a_pass_that_prices_every_link_at_once_links_what_it_links_sensor_by_sensor(
    traffic: dict[str, object], name: str, seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Every sensor's links gated at once, the whole associator: with each link's affordability,
    # edges and anchor's bonus worked out once a pass (`Priced`), or sensor by sensor as before
    # (`Priced.of` made to offer none), every matching of the passes is given the same
    # candidates at the same costs, to the last bit, and the groups and link confidences are
    # the same.
    d = simulate(preset(name, **traffic), seed=seed).detections
    params = AssignmentParams(gate_cost=40.0)  # a wider gate: more candidates near the edges
    seen: list[list[tuple[np.ndarray, ...]]] = [[], []]
    for run in seen:

        def recorded(a: np.ndarray, b: np.ndarray, cost: np.ndarray, gate: float) -> object:
            run.append((a.copy(), b.copy(), cost.copy()))  # noqa: B023 (this run's record)
            return match(a, b, cost, gate)

        monkeypatch.setattr(tracks, "match", recorded)
        associator = AssignmentAssociator(params)
        run.append((associator.group(d), associator.link_confidence))
        monkeypatch.setattr(tracks.Priced, "of", lambda *args: None)
    assert len(seen[0]) == len(seen[1]) >= 10
    for at_once, apart in zip(seen[0], seen[1], strict=True):
        assert all(
            np.array_equal(x, y, equal_nan=True) for x, y in zip(at_once, apart, strict=True)
        )


def test_where_vehicles_join_the_road_one_beside_a_vehicle_at_its_speed_is_a_new_vehicle():
    """A report moments after another of the same sensor at its speed may be a copy of that
    passage, and never starts a track while its twin is linked; but past an on-ramp
    (`ends.RoadEnds`), such a report is a vehicle that just merged in."""
    # Vehicle a (rows 0, 1, 3) past 0, 100 and 200 m; c (rows 2, 4) joins before 100 m, 0.2 s
    # behind a at a's speed; two more vehicles a minute before and after (rows 5-10) hold the
    # batch's window open.
    d = Detections.from_columns(
        position=[0.0, 100.0, 100.0, 200.0, 200.0] + [0.0, 100.0, 200.0] * 2,
        velocity=[20.0] * 5 + [25.0] * 6,
        timestamp=[0.0, 5.0, 5.2, 10.0, 10.2, -60.0, -56.0, -52.0, 60.0, 64.0, 68.0],
    )
    params = AssignmentParams()
    s = arrange(d, params)
    model = segment_prior(s, params.max_skip + 1, params)
    leader = duplicate_followers(s, params)
    assert leader[:5].tolist() == [-1, -1, 1, -1, 3]
    copies = build_tracks(s, model, params, leader, None, 0.0, 1.0)
    assert copies[[2, 4]].tolist() == [-1, -1]  # taken for copies of a's reports
    model.ends = RoadEnds(np.zeros(3), np.array([0.0, 4.0, 0.0]))
    joined = build_tracks(s, model, params, leader, None, 0.0, 1.0)
    assert joined[0] == joined[1] == joined[3] and joined[2] == joined[4] != joined[0]
