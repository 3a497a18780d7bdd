"""Confirmation (`assignment/confirmation.py`): which tracks are targets. False alarms, alone or
chained by loose links, are left out; a track the batch's time window cut short is kept."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams, confirmation
from roadlink.association.associators.assignment.anchors import Anchors
from roadlink.association.associators.assignment.confirmation import (
    confirm_targets,
    ends_explained,
    noisy_sensor_warnings,
    observed_travel,
    starts_explained,
    stored_at_edges,
    track_evidence,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections, concatenate
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import kinematic_model, steady_vehicles

COMMITTED_SUMO = Path(__file__).parents[3] / "data" / "sumo"

PARAMS = AssignmentParams()
ROAD = [0.0, 100.0, 200.0, 300.0, 400.0]


def road_with(extra: Detections) -> Detections:
    """Two vehicles past every sensor (rows 0-9; V0 at 20 m/s from t = 0, V1 at 25 m/s from
    t = 10, so the batch spans 0-26 s), then `extra`'s rows."""
    return concatenate([steady_vehicles([0.0, 10.0], [20.0, 25.0], ROAD), extra])


def confirmed(d: Detections, track: np.ndarray, params: AssignmentParams = PARAMS) -> list[int]:
    s = arrange(d, params)
    return confirm_targets(s, kinematic_model(s.positions.size, params), params, track).tolist()


VEHICLES = [0, 1] * 5


def test_a_lone_report_in_the_middle_of_road_and_batch_is_a_false_alarm():
    d = road_with(Detections.from_columns([200.0], [22.0], [12.0]))
    assert confirmed(d, np.array([*VEHICLES, 2])) == [*VEHICLES, -1]


def test_a_lone_report_the_window_cut_is_a_target():
    # At the first sensor 0.5 s before the batch ends (it cannot reach the next one inside it),
    # and at the last sensor 0.5 s after it began (it passed the one before earlier): targets.
    d = road_with(Detections.from_columns([0.0, 400.0], [20.0, 20.0], [25.5, 0.5]))
    assert confirmed(d, np.array([*VEHICLES, 2, 3])) == [*VEHICLES, 2, 3]
    # The same reports in the middle of the batch would have been seen again: false alarms.
    d = road_with(Detections.from_columns([0.0, 400.0], [20.0, 20.0], [10.5, 13.0]))
    assert confirmed(d, np.array([*VEHICLES, 2, 3])) == [*VEHICLES, -1, -1]


def test_false_alarms_chained_by_a_loose_link_are_left_out_and_a_tight_pair_is_kept():
    # Two reports 100 m apart at 20 m/s: 5 s is the kinematic travel time. 6.8 s is 3.6 spreads
    # late: the link is within the gate but saves less than min_track_evidence.
    loose = road_with(Detections.from_columns([100.0, 200.0], [20.0, 20.0], [3.0, 9.8]))
    assert confirmed(loose, np.array([*VEHICLES, 2, 2])) == [*VEHICLES, -1, -1]
    tight = road_with(Detections.from_columns([100.0, 200.0], [20.0, 20.0], [3.0, 8.0]))
    assert confirmed(tight, np.array([*VEHICLES, 2, 2])) == [*VEHICLES, 2, 2]
    # A target must also be long enough, unless the window explains it.
    assert confirmed(tight, np.array([*VEHICLES, 2, 2]), AssignmentParams(min_track_length=3)) == [
        *VEHICLES,
        -1,
        -1,
    ]


def test_targets_are_numbered_from_zero_in_track_order():
    d = road_with(Detections.from_columns([200.0], [22.0], [12.0]))
    track = np.array([7, 4] * 5 + [5])
    assert confirmed(d, track) == [1, 0] * 5 + [-1]
    assert confirmed(d, np.full(11, -1)) == [-1] * 11


def evidence_of_a_loose_pair(anchors: Anchors | None = None) -> np.ndarray:
    """The evidence of the two vehicles' tracks and of a pair of reports linked loosely (rows 10
    and 11: 100 m in 6.8 s at 20 m/s, where 5 s is exact)."""
    d = road_with(Detections.from_columns([100.0, 200.0], [20.0, 20.0], [3.0, 9.8]))
    s = arrange(d, PARAMS)
    model = kinematic_model(5, PARAMS)
    track = np.array([*VEHICLES, 2, 2])
    chain = np.flatnonzero(track >= 0)
    chain = chain[np.lexsort((s.sensor[chain], track[chain]))]
    return track_evidence(s, model, PARAMS, chain, track[chain], anchors)


def test_evidence_is_what_the_links_save_over_leaving_their_detections_apart():
    evidence = evidence_of_a_loose_pair()
    # The vehicles' links are exact in time and speed: each of the four saves nearly the whole
    # gate cost (the pace term sees speeds relative to each sensor's median, which the extra
    # reports move a little).
    assert evidence[:2] == pytest.approx([4 * PARAMS.gate_cost] * 2, rel=0.01)
    # The loose link saves something, less than a target needs.
    assert 0.0 < evidence[2] < PARAMS.min_track_evidence


def test_an_anchored_link_counts_its_anchor_as_evidence():
    plain = evidence_of_a_loose_pair()
    predecessor = np.full(12, -1)
    predecessor[11] = 10  # the loose link, anchored by its lane's order
    bonus = np.where(predecessor >= 0, 5.0, 0.0)
    anchored = evidence_of_a_loose_pair(Anchors(predecessor, bonus))
    assert anchored[:2] == pytest.approx(plain[:2])
    assert anchored[2] == pytest.approx(plain[2] + 5.0)
    # Enough to make the pair a target, as the linking that chose it for its anchor judged.
    assert anchored[2] >= PARAMS.min_track_evidence


def test_a_track_start_and_end_are_explained_by_the_road_or_the_window():
    d = road_with(Detections.from_columns([], [], []))
    s = arrange(d, PARAMS)
    model = kinematic_model(5, PARAMS)
    # V0's first detection is at the first sensor; V1's (row 5, at 200 m, t = 18) is not, and
    # the batch began 18 s earlier, time to pass the sensor before.
    assert starts_explained(s, model, np.array([0, 5])).tolist() == [True, False]
    # V0's detection at 400 m is at the last sensor; V1's at 300 m (t = 22) would reach 400 m
    # after the batch ends (26 s); V0's at 100 m (t = 5) would not.
    assert ends_explained(s, model, np.array([8, 7, 2])).tolist() == [True, True, False]


def test_a_weak_track_is_judged_detection_by_detection():
    # A bad link (100 m in 0.9 s at 20 m/s, where 5 s is exact) saves nothing. Its first
    # detection, at the first sensor half a second before the batch ends, is a vehicle the window
    # cut (kept as a target of its own); its second, mid-road 25.9 s into the batch, is not
    # explained by the window: a false alarm.
    d = road_with(Detections.from_columns([0.0, 100.0], [20.0, 20.0], [25.5, 25.9]))
    assert confirmed(d, np.array([*VEHICLES, 2, 2])) == [*VEHICLES, 2, -1]


def counted(counts: list[int]) -> Detections:
    """Sensors 100 m apart, each with `counts[k]` reports one second apart from t = 0."""
    return Detections.from_columns(
        np.repeat(100.0 * np.arange(len(counts)), counts),
        np.full(sum(counts), 10.0),
        np.concatenate([np.arange(n, dtype=float) for n in counts]),
    )


def stored(counts: list[int]) -> tuple[list[int], list[int]]:
    """The detections `stored_at_edges` explains at the batch's start and at its end, as
    (sensor, rank by time at that sensor)."""
    d = counted(counts)
    s = arrange(d, PARAMS)
    first, last = stored_at_edges(s)
    rank = np.empty(len(d), dtype=np.int64)
    rank[s.order] = np.arange(len(d)) - np.repeat(s.start[:-1], np.diff(s.start))
    return [sorted(zip(s.sensor[m].tolist(), rank[m].tolist(), strict=True)) for m in (first, last)]


def test_a_queue_between_two_sensors_explains_its_surplus_at_the_batch_edges():
    # 40 vehicles passed the first sensor, 10 the second: at least 30 were still between them
    # when the batch ended, the first sensor's last 30.
    first, last = stored([40, 10, 10])
    assert first == [] and last == [(0, rank) for rank in range(10, 40)]
    # And 30 more at the last sensor than at the one before entered before the batch began.
    first, last = stored([10, 10, 40])
    assert first == [(2, rank) for rank in range(30)] and last == []


def test_false_alarms_and_chance_explain_no_queue():
    # A sensor that counted more than both neighbours has false alarms, not a queue.
    assert stored([20, 60, 20]) == [[], []]
    # A surplus within three Poisson deviations of the smaller count is chance.
    assert stored([33, 20, 20]) == [[], []]
    assert stored([34, 20, 20])[1] == [(0, rank) for rank in range(20, 34)]


def test_a_segments_observed_travel_time_is_its_links_long_tail():
    # Six vehicles over three sensors 100 m apart; the first segment's links take 10-15 s, the
    # second's two are too few to read.
    times = np.arange(6.0)
    d = Detections.from_columns(
        np.r_[np.zeros(6), np.full(6, 100.0), np.full(2, 200.0)],
        np.full(14, 10.0),
        np.r_[times, times + 10.0 + times, [40.0, 41.0]],
    )
    s = arrange(d, PARAMS)
    track = np.r_[np.arange(6), np.arange(6), [4, 5]]
    chain = s.by_track(np.arange(14), track)
    longest = observed_travel(s, chain, track[chain])
    assert longest.tolist() == [pytest.approx(np.quantile(10.0 + times, 0.9)), 0.0]


def test_the_committed_queue_leaves_fewer_vehicles_unassigned():
    # SUMO's queue (seed 0) has no false alarm: the queue held vehicles between sensors past the
    # batch's end, and its links fit hardly better than chance. 65 of 1,229 detections were
    # left unassigned before the queue's counts and travel times explained them; 26 now.
    d = read_detections_csv((COMMITTED_SUMO / "sumo-queue.csv").read_bytes())
    groups = associate(d.without_labels(), "assignment").groups
    assert (groups < 0).sum() <= 30


def _in_units(d: Detections, position: float = 1.0, time: float = 1.0) -> Detections:
    return Detections.from_columns(
        d.position * position, d.velocity, d.timestamp * time, target=list(d.target)
    )


@pytest.mark.parametrize("case", ["positions in km", "times in ms"])
def test_a_batch_whose_units_fit_no_vehicle_says_so(case, caplog):
    d = simulate(preset("medium"), seed=0).detections
    bad = {
        "positions in km": _in_units(d, position=1e-3),
        "times in ms": _in_units(d, time=1e3),
    }[case]
    result = associate(bad, "assignment")
    assert any("could be linked to another: check that positions" in w for w in result.warnings)
    assert "matching units" in caplog.text
    assert not associate(d, "assignment").warnings


@pytest.mark.parametrize(
    "case", ["paper:medium", "paper:congested", "sumo-freeflow", "sumo-dense", "sumo-arterial"]
)
def test_a_road_numbered_against_the_traffic_says_so(case):
    # In free flow nothing is linked; in dense traffic the wrong vehicles were (98.7 % of the
    # detections linked, and no word): the nearest partner where speeds say, earlier, fits
    # about four times better than later (0.8 % of a travel time against 2.9 % in SUMO's dense
    # traffic).
    if case.startswith("paper:"):
        d = simulate(preset(case.removeprefix("paper:")), seed=0).detections
    else:
        d = read_detections_csv(COMMITTED_SUMO / f"{case}.csv").without_features()
    reversed_road = _in_units(d, position=-1.0)
    (warning,) = associate(reversed_road, "assignment").warnings
    assert warning.startswith("the detections fit vehicles driving towards decreasing positions")
    assert not associate(d, "assignment").warnings


@pytest.mark.parametrize("case", ["sumo-queue", "sumo-stopgo"])
def test_in_a_queue_the_direction_is_not_guessed(case):
    # Crawling vehicles' speeds tell travel times poorly either way: nothing is said.
    d = read_detections_csv(COMMITTED_SUMO / f"{case}.csv").without_features()
    assert not associate(_in_units(d, position=-1.0), "assignment").warnings


def _with_false_alarms(d: Detections, position: float, share: float, seed: int) -> Detections:
    """`d` with false alarms at the sensor at `position`: `share` of its count more reports at
    uniform times and speeds within its own."""
    rng = np.random.default_rng(seed)
    at = d.position == position
    n = int(share * at.sum())
    v, t = d.velocity[at], d.timestamp
    return concatenate(
        [
            d,
            Detections.from_columns(
                np.full(n, position),
                rng.uniform(v.min(), v.max(), n),
                rng.uniform(t.min(), t.max(), n),
                target=["clutter"] * n,
            ),
        ]
    )


@pytest.mark.parametrize("case", ["sumo-dense", "sumo-freeflow", "sumo-faulty"])
def test_a_sensor_reporting_half_again_its_vehicles_as_false_alarms_is_named(case, caplog):
    d = read_detections_csv(COMMITTED_SUMO / f"{case}.csv")
    noisy = _with_false_alarms(d, 1450.0, 0.5, seed=1)
    warnings = associate(noisy, "assignment").warnings
    assert len(warnings) == 1
    assert warnings[0].startswith("the sensor at position 1450 reported 1.")
    assert "joined no vehicle: false alarms" in caplog.text
    assert not associate(d, "assignment").warnings


@pytest.mark.parametrize("case", ["sumo-queue", "sumo-stopgo", "sumo-bottleneck"])
def test_a_queue_that_stores_vehicles_between_sensors_names_no_sensor(case):
    # The sensor before a queue sees more vehicles than the next, many never linked inside the
    # batch: but not more than the sensor before it.
    d = read_detections_csv(COMMITTED_SUMO / f"{case}.csv")
    assert not noisy_sensor_warnings(arrange(d, AssignmentParams()), associate(d).groups)


def test_a_sensor_is_named_only_above_both_neighbours_with_its_extra_reports_unlinked():
    # Sensors 200 m apart with 100, 160, 100, 100 reports; the second's 60 extra unlinked.
    counts = [100, 160, 100, 100]
    d = Detections.from_columns(
        np.repeat(200.0 * np.arange(4), counts),
        np.full(sum(counts), 20.0),
        np.concatenate([np.arange(n, dtype=np.float64) for n in counts]),
    )
    s = arrange(d, AssignmentParams())
    target = np.zeros(len(d), dtype=np.int64)
    second = np.flatnonzero(d.position == 200.0)
    target[second[:60]] = -1
    (warning,) = noisy_sensor_warnings(s, target)
    assert warning.startswith("the sensor at position 200 reported 1.6 times")
    assert "60 of them (38%) joined no vehicle" in warning
    # Half of them unlinked: not false alarms by count. Its neighbour as busy: a queue's edge.
    target[second[:60]] = 0
    target[second[:20]] = -1
    assert not noisy_sensor_warnings(s, target)
    d_queue = Detections.from_columns(
        np.repeat(200.0 * np.arange(4), [160, 160, 100, 100]),
        np.full(520, 20.0),
        np.concatenate([np.arange(n, dtype=np.float64) for n in [160, 160, 100, 100]]),
    )
    unlinked = np.zeros(520, dtype=np.int64)
    unlinked[160:220] = -1
    assert not noisy_sensor_warnings(arrange(d_queue, AssignmentParams()), unlinked)


def test_observed_travel_is_the_same_sorted_at_once_or_segment_by_segment(monkeypatch):
    d = read_detections_csv((COMMITTED_SUMO / "sumo-queue.csv").read_bytes()).without_labels()
    s = arrange(d, PARAMS)
    # Links between each sensor's k-th and the next sensor's k-th detections: a queue's counts.
    rank = np.arange(len(d)) - np.repeat(s.start[:-1], np.diff(s.start))
    track = np.empty(len(d), dtype=np.int64)
    track[s.order] = rank
    chain = s.by_track(np.arange(len(d)), track)
    at_once = observed_travel(s, chain, track[chain])
    monkeypatch.setattr(confirmation, "OBSERVED_AT_ONCE_LINKS", 0)
    by_segment = observed_travel(s, chain, track[chain])
    assert np.count_nonzero(at_once) == s.positions.size - 1  # every segment read
    assert at_once.tolist() == by_segment.tolist()
