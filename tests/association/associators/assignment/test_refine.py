"""Re-pairing with hindsight (`assignment/refine.py`): at every sensor boundary track prefixes are
matched to suffixes again, which undoes a swap, joins fragments, keeps right tracks as they are,
and judges every link it keeps."""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentParams, refine
from roadlink.association.associators.assignment.anchors import Anchors
from roadlink.association.associators.assignment.associator import link_and_learn
from roadlink.association.associators.assignment.ends import RoadEnds
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import REFINE_GATE_FACTOR, within_time_scale
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.refine import (
    Judged,
    Judging,
    Summed,
    Unchanged,
    _tracks_again,
    fragment_ends,
    refine_boundaries,
    suffix_sums,
)
from roadlink.association.associators.assignment.sensors import Sensors, arrange
from roadlink.association.associators.assignment.tracks import (
    level_terms,
    successors,
    tracks_from_links,
)
from roadlink.simulation import SimulationConfig, preset, simulate
from tests.association.associators.assignment.roads import kinematic_model, steady_vehicles

PARAMS = AssignmentParams()
ROAD = [0.0, 100.0, 200.0, 300.0, 400.0]
# V0 at 20 m/s from t = 0 and V1 at 30 m/s from t = 1.5: V1 overtakes V0 just before 100 m.
# Rows are sensor by sensor, V0 then V1: V0 is rows 0, 2, 4, 6, 8.
TRUTH = np.array([0, 1] * 5)


def sweep(track: np.ndarray, **kwargs: object) -> tuple[list[int], bool]:
    """The tracks after one sweep over the test road, and whether it changed a link."""
    d = steady_vehicles([0.0, 1.5], [20.0, 30.0], ROAD)
    s = arrange(d, PARAMS)
    model = kinematic_model(len(ROAD), PARAMS)
    after, changed = refine_boundaries(s, model, PARAMS, track.copy(), **kwargs)  # type: ignore[arg-type]
    return after.tolist(), changed


def refined(track: np.ndarray, **kwargs: object) -> list[int]:
    return sweep(track, **kwargs)[0]


def test_right_tracks_are_kept_as_they_are():
    assert refined(TRUTH) == TRUTH.tolist()


def test_a_swap_between_two_targets_is_undone():
    swapped = TRUTH.copy()
    swapped[6:] = 1 - swapped[6:]  # from 300 m on, each track follows the other vehicle
    assert refined(swapped) == TRUTH.tolist()


def test_fragments_of_one_target_are_joined():
    fragments = TRUTH.copy()
    fragments[[4, 6, 8]] = 2  # V0 from 200 m on, a track of its own
    assert refined(fragments) == TRUTH.tolist()


def test_the_links_kept_are_judged_and_without_relinking_the_wrong_one_is_judged_wrong():
    confidence = np.full(TRUTH.size, np.nan)
    refined(TRUTH, confidence=confidence)
    assert np.isnan(confidence[:2]).all()  # a track's first detection has no link into it
    assert confidence[2:] == pytest.approx(np.ones(8), abs=1e-3)

    swapped = TRUTH.copy()
    swapped[6:] = 1 - swapped[6:]
    judged = np.full(TRUTH.size, np.nan)
    assert refined(swapped, confidence=judged, relink=False) == swapped.tolist()
    # V0's link from 200 m into V1's detection at 300 m is surely wrong; V1's link into V0's
    # is too far off in time to be a candidate at all, so it is not judged.
    assert judged[6] < 1e-3 and np.isnan(judged[7])
    # Two vehicles over a few seconds are all window edge, where a detection is likelier to have
    # no partner in the batch (`edges.py`): the sure links are a little less than certain.
    assert judged[2:6] == pytest.approx(np.ones(4), abs=3e-3)


def test_a_tentative_judging_stops_at_the_first_change_and_a_sweep_says_whether_it_changed():
    # A sweep that changes no link judges every link (the next sweep would do the same work);
    # one that changes a link stops judging there.
    kept = np.full(TRUTH.size, np.nan)
    assert sweep(TRUTH, confidence=kept, tentative=True) == (TRUTH.tolist(), False)
    assert kept[2:] == pytest.approx(np.ones(8), abs=1e-3)
    swapped = TRUTH.copy()
    swapped[6:] = 1 - swapped[6:]
    judged = np.full(TRUTH.size, np.nan)
    assert sweep(swapped, confidence=judged, tentative=True) == (TRUTH.tolist(), True)
    assert np.isnan(judged[6:]).all()  # the swap is undone at the boundary before 300 m


def test_suffix_sums_run_from_each_detection_to_its_tracks_end():
    d = steady_vehicles([0.0, 1.5], [20.0, 30.0], ROAD)
    s = arrange(d, PARAMS)
    nxt, _ = successors(s, TRUTH)
    total, count = suffix_sums(s, nxt, np.arange(10.0), np.ones(10))
    # V0's rows are 0, 2, 4, 6, 8: from row 4 on, 4 + 6 + 8 over three detections.
    assert total[[0, 4, 8]].tolist() == [20.0, 18.0, 8.0]
    assert count[[0, 4, 8]].tolist() == [5.0, 3.0, 1.0]


def _boundary_into_sensor_1() -> tuple[Sensors, SegmentModel, tuple[np.ndarray, np.ndarray], Pairs]:
    """The test road, V0 linked 0 -> 100 m (rows 0 -> 2), V1's rows 1 and 3 each alone, and the
    candidate links into sensor 1: 0 -> 2 (both held), 1 -> 3 (both ends loose), 0 -> 3 (one
    loose)."""
    s = arrange(steady_vehicles([0.0, 1.5], [20.0, 30.0], ROAD), PARAMS)
    nxt, prv = np.full(10, -1), np.full(10, -1)
    nxt[0], prv[2] = 2, 0
    pairs = Pairs(
        np.array([0, 1, 0]),
        np.array([2, 3, 3]),
        np.zeros(3),
        np.zeros(3),
        np.ones(3),
        np.ones(3, dtype=np.int64),
    )
    return s, kinematic_model(len(ROAD), PARAMS), (nxt, prv), pairs


HALF_DIFFERENCE = (REFINE_GATE_FACTOR - 1.0) * PARAMS.gate_cost / 2.0


def test_joining_fragments_pays_the_forward_pass_gate_where_anchors_weigh():
    s, model, links, pairs = _boundary_into_sensor_1()
    anchors = Anchors(np.full(10, -1), np.zeros(10), weight=np.array([1.0, 0.0, 0.0, 0.0]))
    assert fragment_ends(s, PARAMS, anchors, model, 0, links, pairs).tolist() == pytest.approx(
        [0.0, 2 * HALF_DIFFERENCE, HALF_DIFFERENCE]
    )
    # Where the segment's anchors do not weigh (free flow), or there are none, nothing.
    free = Anchors(np.full(10, -1), np.zeros(10), weight=np.zeros(4))
    assert not fragment_ends(s, PARAMS, free, model, 0, links, pairs).any()
    assert not fragment_ends(s, PARAMS, None, model, 0, links, pairs).any()


def test_joining_fragments_pays_the_forward_pass_gate_where_vehicles_leave_or_join():
    """A prefix that ends where vehicles leave the road, or a suffix that starts where they join
    it (`ends.RoadEnds`), is a fragment by right: joining it pays what the forward pass would."""
    s, model, links, pairs = _boundary_into_sensor_1()
    model.ends = RoadEnds(np.array([3.0, 0, 0, 0, 0]), np.zeros(5))  # vehicles leave after 0 m
    assert fragment_ends(s, PARAMS, None, model, 0, links, pairs).tolist() == pytest.approx(
        [0.0, HALF_DIFFERENCE, 0.0]  # the loose prefix (row 1) pays, the loose suffix does not
    )
    model.ends = RoadEnds(np.zeros(5), np.array([0, 3.0, 0, 0, 0]))  # they join before 100 m
    assert fragment_ends(s, PARAMS, None, model, 0, links, pairs).tolist() == pytest.approx(
        [0.0, HALF_DIFFERENCE, HALF_DIFFERENCE]
    )
    # Elsewhere on the road nothing changes.
    model.ends = RoadEnds(np.array([0, 3.0, 0, 0, 0]), np.array([0, 0, 3.0, 0, 0]))
    assert not fragment_ends(s, PARAMS, None, model, 0, links, pairs).any()


FAULTS = {"miss_probability": 0.1, "false_alarm_rate": 0.02, "velocity_noise": 0.03}
FEATURES = {"lanes": 3, "vehicle_lengths": True, "length_noise": 0.05, "miss_probability": 0.1}


@pytest.mark.parametrize("traffic", [{}, FAULTS, FEATURES])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_sweep_worked_out_at_once_is_the_sweep_boundary_by_boundary(
    traffic: dict[str, object], seed: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # Paper-size batches (every sensor's links gated at once), after the associator's linking:
    # tracks, whether a link changed, and every confidence to the bit, whether the sweep
    # changes links (then it is made boundary by boundary) or not, judging alone or relinking;
    # and at once with every boundary's matching solved (none taken as sure).
    s = arrange(simulate(preset("large", **traffic), seed=seed).detections, PARAMS)
    params = within_time_scale(PARAMS, s.typical_travel_time())
    prior = segment_prior(s, params.max_skip + 1, params)
    track, model, anchor = link_and_learn(s, params, prior, prior, params.em_rounds + 1)
    if seed == 2:
        # Tracks cut in two halfway along the road: fragments to join, links change.
        cut = (track >= 0) & (track % 2 == 0) & (s.sensor >= s.positions.size // 2)
        track = np.where(cut, track + track.max() + 1, track)
    options: list[dict[str, object]] = [{}, {"tentative": True}, {"relink": False}]
    found = []
    for way in ("at once", "solved", "plain"):
        if way == "solved":
            monkeypatch.setattr(refine, "sure_matchings", lambda *args: np.zeros(99, dtype=bool))
        if way == "plain":
            monkeypatch.setattr(Unchanged, "sweep", lambda *_: None)
        for option in options:
            confidence = np.full(track.size, np.nan)
            after, changed = refine_boundaries(
                s, model, params, track.copy(), confidence, anchor=anchor, **option
            )  # type: ignore[arg-type]
            found.append((after, changed, confidence))
    for k, (after, changed, confidence) in enumerate(found[3:]):
        plain_after, plain_changed, plain_confidence = found[k % 3]
        assert np.array_equal(after, plain_after) and changed == plain_changed
        assert np.array_equal(confidence, plain_confidence, equal_nan=True)
    if seed == 2:
        assert found[0][1]  # the fragments were joined


def test_judging_calls_each_run_of_small_boundaries_together_and_holds_one_run(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Boundaries of 3, 4, 5, 20, 0, 2 and 30 links, JUDGED_AT_ONCE 10: the links so far are
    # 3, 7, 12, 32, 32, 34, 64, so the calls judge [3, 4], [5], [20, 0, 2], [30]; a call is
    # made as soon as the next boundary starts another, so only the current run is held.
    monkeypatch.setattr(refine, "JUDGED_AT_ONCE", 10)
    calls: list[list[int]] = []
    monkeypatch.setattr(
        refine,
        "judge_together",
        lambda _, judged, __: calls.append([pairs.a.size for pairs, _, _ in judged]),
    )
    judging = Judging(np.full(1, np.nan), PARAMS.gate_cost)
    held = []
    for size in (3, 4, 5, 20, 0, 2, 30):
        links = np.zeros(size, dtype=np.int64)
        pairs = Pairs(links, links, np.zeros(size), np.zeros(size), np.ones(size), links)
        judging.add((pairs, np.zeros(size), np.zeros(size, dtype=bool)))
        held.append([p.a.size for p, _, _ in judging.pending])
    judging.finish()
    assert calls == [[3, 4], [5], [20, 0, 2], [30]]
    assert held == [[3], [3, 4], [5], [20], [20, 0], [20, 0, 2], [30]]


@dataclass(frozen=True)
class Linked:
    """The scaling benchmark's traffic (a target a second at 20-40 m/s, fluctuating), short:
    ten detections a sensor, so the sweep is made boundary by boundary; after the
    associator's linking, ready for its sweep."""

    s: Sensors
    params: AssignmentParams
    model: SegmentModel
    track: np.ndarray
    anchor: Anchors | None

    @classmethod
    def dense(cls, n_targets: int = 200, n_sensors: int = 20) -> Linked:
        config = SimulationConfig(
            n_targets=n_targets,
            sensor_positions=[100.0 * i for i in range(n_sensors)],
            velocity_range=(20.0, 40.0),
            start_time_range=(0.0, float(n_targets)),
        )
        s = arrange(simulate(config, seed=3).detections, PARAMS)
        params = within_time_scale(PARAMS, s.typical_travel_time())
        prior = segment_prior(s, params.max_skip + 1, params)
        track, model, anchor = link_and_learn(s, params, prior, prior, params.em_rounds + 1)
        return cls(s, params, model, track, anchor)

    def sweep(self) -> tuple[np.ndarray, np.ndarray]:
        """The tracks after one sweep, and the confidences it judged."""
        confidence = np.full(self.track.size, np.nan)
        after, _ = refine_boundaries(
            self.s, self.model, self.params, self.track.copy(), confidence, anchor=self.anchor
        )
        return after, confidence


def test_a_sweep_judges_the_same_whichever_boundaries_are_judged_together(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Each boundary's nodes are numbered apart, so judging boundaries one by one (as a large
    # batch's are, each holding its own links) or all in one call gives every confidence to
    # the bit, and the same tracks.
    linked = Linked.dense()
    found = []
    for at_once in (1, refine.JUDGED_AT_ONCE, 10**9):
        monkeypatch.setattr(refine, "JUDGED_AT_ONCE", at_once)
        found.append(linked.sweep())
    for after, confidence in found[1:]:
        assert np.array_equal(after, found[0][0])
        assert np.array_equal(confidence, found[0][1], equal_nan=True)
    assert np.isfinite(found[0][1]).sum() > linked.track.size // 2  # most links judged


def test_a_sweep_holds_the_links_of_a_boundary_or_two_not_of_every_boundary(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # Where every boundary has more links than are judged together, each boundary's candidate
    # links are judged, and freed, as the sweep goes: at 10^6 detections holding every
    # boundary's until the end of the sweep made most of the association's peak memory.
    linked = Linked.dense()
    monkeypatch.setattr(refine, "JUDGED_AT_ONCE", 64)
    judge_together = refine.judge_together
    costs: list[weakref.ref[np.ndarray]] = []
    alive = []

    def judged(confidence: np.ndarray, boundaries: list[Judged], gate: float) -> None:
        alive.append(sum(cost() is not None for cost in costs))  # of the boundaries judged
        costs.extend(weakref.ref(cost) for _, cost, _ in boundaries)
        judge_together(confidence, boundaries, gate)

    monkeypatch.setattr(refine, "judge_together", judged)
    linked.sweep()
    assert len(costs) == len(alive) == linked.s.positions.size - 1  # each boundary alone
    assert max(alive) == 0


@pytest.mark.parametrize("seed", [0, 1])
def test_tracks_read_again_from_their_links_are_numbered_as_tracks_from_links_numbers_them(
    seed: int,
) -> None:
    # A forward pass's tracks (numbered by their births, as tracks_from_links numbers them),
    # the same renumbered, and with a detection left out: read again from their own links,
    # each is what tracks_from_links makes of them.
    s = arrange(simulate(preset("medium", miss_probability=0.1), seed=seed).detections, PARAMS)
    prior = segment_prior(s, PARAMS.max_skip + 1, PARAMS)
    track, _, _ = link_and_learn(s, PARAMS, prior, prior, 1)
    renumbered = np.where(track >= 0, track.max() - track, -1)
    cut = track.copy()
    cut[s.members(3)[0]] = -1
    for tracks in (track, renumbered, cut):
        _, prv = successors(s, tracks)
        in_track = tracks >= 0
        again = _tracks_again(s, tracks, prv, in_track)
        assert np.array_equal(again, tracks_from_links(s, prv, in_track))
    assert np.array_equal(_tracks_again(s, track, successors(s, track)[1], track >= 0), track)


@pytest.mark.parametrize("traffic", [{}, FAULTS, FEATURES])
def test_running_sums_along_every_track_at_once_are_those_extended_sensor_by_sensor(
    traffic: dict[str, object],
) -> None:
    # Prefix sums (to the last sensor but one, as a sweep that keeps its links extends them)
    # and suffix sums of each level term, for every track at once or sensor by sensor: the
    # same numbers to the bit.
    s = arrange(simulate(preset("medium", **traffic), seed=4).detections, PARAMS)
    prior = segment_prior(s, PARAMS.max_skip + 1, PARAMS)
    track, _, _ = link_and_learn(s, PARAMS, prior, prior, 1)
    nxt, prv = successors(s, track)
    for value, weight in level_terms(s):
        at_once = Summed.along(s, value, weight, track)
        by_sensor = Summed.of(s, value, weight, nxt, track >= 0)
        for q in range(s.positions.size - 1):
            m = s.members(q)
            m = m[prv[m] >= 0]
            by_sensor.extend_heads(m, prv[m])
        for field in ("weight", "head_sum", "head_count", "tail_sum", "tail_count"):
            assert np.array_equal(getattr(at_once, field), getattr(by_sensor, field))
        assert (at_once.head_count > 1).sum() > 50
