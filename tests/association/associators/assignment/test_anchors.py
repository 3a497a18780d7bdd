"""assignment/anchors.py: lane-order anchors, and what they do for `assignment` in a queue."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import anchors, first_chains
from roadlink.association.associators.assignment.anchors import (
    ANCHOR_BONUS,
    SKIP_CHANCES,
    lane_destinations,
    lane_order_anchors,
    skip_costs,
    track_lengths,
    weigh_anchors,
)
from roadlink.association.associators.assignment.chains import (
    SKIP,
    smooth_chain,
)
from roadlink.association.associators.assignment.first_chains import learned_smoothness
from roadlink.association.associators.assignment.learning import learn_segments
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from tests.association.associators.assignment.test_chains import chain_case
from tests.helpers import lane_queue

SUMO_FEATURES = Path(__file__).parents[3] / "data" / "sumo-features"


def test_a_queue_chain_runs_on_through_vehicles_that_lengths_cannot_tell_apart() -> None:
    gain, log_travel, kinematic = chain_case(offset=2, n=40, wait=0.05)
    # Every true pair gains little (cars alike), but two trucks pin the alignment.
    gain = np.where(np.isfinite(gain), gain - 0.5, gain)
    gain[5, 7] = gain[30, 32] = 6.0
    smoothness = learned_smoothness([(gain, log_travel, kinematic)])
    pairs = smooth_chain(gain, log_travel, kinematic, smoothness)
    right = sum(j == i + 2 for i, j in pairs)
    assert right >= 36 and right == len(pairs)


def test_anchors_in_a_lane_keeping_queue_are_right_and_cover_most_vehicles() -> None:
    d = lane_queue()
    params = AssignmentParams()
    s = arrange(d, params)
    chains = lane_order_anchors(s, segment_prior(s, params.max_skip + 1, params), params)
    anchor, margin = chains.predecessor, chains.margin
    assert (margin[anchor >= 0] > 0).all() and (margin[anchor < 0] == 0).all()
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
    sure = np.full(len(d), 100.0)
    calm = weigh_anchors(s, predecessor, sure, agreeing)
    assert (calm.bonus == 0.0).all()
    shaken = weigh_anchors(s, predecessor, sure, lost)
    into_last = (predecessor >= 0) & (s.sensor == 2)
    assert np.allclose(shaken.bonus[into_last], ANCHOR_BONUS)
    assert (shaken.bonus[~into_last] == 0.0).all()
    # An anchor earns as much as its chain beat its rivals by (-2 log odds), within the bonus.
    margin = np.where(np.arange(len(d)) % 2 == 0, 3.0, 0.0)
    weighed = weigh_anchors(s, predecessor, margin, lost)
    assert np.allclose(weighed.bonus[into_last], 2.0 * margin[into_last])


def steady_crawl(seed: int) -> Detections:
    """Two lanes crawling at 1.6 m/s past three sensors 200 m apart (125 s a segment), cars
    alone (3.6-5.4 m, read with a 7 % error), in a 240 s window: each sensor sees about as many
    vehicles that the one before saw before the window opened as it sees vehicles it can link."""
    rng = np.random.default_rng(seed)
    gap, speed = 200.0, 1.6
    rows: list[tuple[float, float, float, str, int, float]] = []
    for lane in (0, 1):
        entries = np.cumsum(rng.uniform(0.8, 1.2, 120) * 5.0) - 250.0
        length = rng.uniform(3.6, 5.4, entries.size)
        for vehicle, (entry, true_length) in enumerate(zip(entries, length, strict=True)):
            for sensor in range(3):
                passed = entry + sensor * gap / speed + rng.normal(0.0, 1.0)
                if 0.0 <= passed <= 240.0:
                    reading = true_length * (1 + 0.07 * rng.standard_normal())
                    measured = speed * (1 + 0.1 * rng.standard_normal())
                    rows.append(
                        (sensor * gap, measured, passed, f"v{lane}.{vehicle}", lane, reading)
                    )
    position, velocity, timestamp, target, lanes, lengths = zip(*rows, strict=True)
    return Detections.from_columns(
        position, velocity, timestamp, target=target, lane=lanes, length=lengths
    )


def anchors_right(d: Detections) -> float:
    params = AssignmentParams()
    s = arrange(d, params)
    anchor = lane_order_anchors(
        s, segment_prior(s, params.max_skip + 1, params), params
    ).predecessor
    anchored = np.flatnonzero(anchor >= 0)
    labels = d.target.astype(str)
    return float(np.mean(labels[anchor[anchored]] == labels[anchored]))


def test_in_a_steady_crawl_the_speeds_keep_the_chains_from_drifting(monkeypatch) -> None:
    cases = [steady_crawl(seed) for seed in range(3)]
    # Lengths alike and a window shorter than two crossings: a chain that matched each lane's
    # first detections to each other would link more pairs, all of them wrong. The kinematic
    # travel time (125 s, not 50) keeps most chains where they belong.
    assert np.mean([anchors_right(d) for d in cases]) >= 0.4
    monkeypatch.setattr(first_chains, "KINEMATIC_SPREAD", 1e6)
    assert np.mean([anchors_right(d) for d in cases]) <= 0.1


def lane_queue_anchors(d: Detections) -> tuple[np.ndarray, np.ndarray]:
    params = AssignmentParams()
    s = arrange(d, params)
    chains = lane_order_anchors(s, segment_prior(s, params.max_skip + 1, params), params)
    return chains.predecessor, chains.margin


def test_no_anchors_without_lanes() -> None:
    d = lane_queue()
    for blind in (
        Detections.from_columns(d.position, d.velocity, d.timestamp, target=d.target),
        Detections.from_columns(
            d.position, d.velocity, d.timestamp, target=d.target, length=d.length
        ),
    ):
        anchor, margin = lane_queue_anchors(blind)
        assert (anchor < 0).all() and (margin == 0).all()


def lanes_alone(d: Detections) -> Detections:
    return Detections.from_columns(
        d.position, d.velocity, d.timestamp, target=d.target, lane=d.lane
    )


def test_lanes_alone_anchor_a_lane_keeping_queue_by_time() -> None:
    d = lane_queue()
    anchor, _ = lane_queue_anchors(lanes_alone(d))
    anchored = np.flatnonzero(anchor >= 0)
    labels = d.target.astype(str)
    # Time alone pins fewer chains than time and length, but those it pins are right.
    assert anchored.size >= 0.5 * np.count_nonzero(lane_queue_anchors(d)[0] >= 0)
    assert np.mean(labels[anchor[anchored]] == labels[anchored]) >= 0.95


def test_a_pair_without_both_lengths_keeps_a_share_of_its_margin(monkeypatch) -> None:
    d = lanes_alone(lane_queue())
    monkeypatch.setattr(anchors, "LANE_ONLY_MARGIN", 1.0)
    full_anchor, full_margin = lane_queue_anchors(d)
    monkeypatch.setattr(anchors, "LANE_ONLY_MARGIN", 0.5)
    anchor, margin = lane_queue_anchors(d)
    assert (anchor >= 0).sum() >= 50 and (full_margin[anchor >= 0] > 0).all()
    np.testing.assert_array_equal(anchor, full_anchor)
    np.testing.assert_allclose(margin, 0.5 * full_margin)


def test_a_detection_without_a_length_stays_in_its_lanes_chain() -> None:
    d = lane_queue()
    length = d.length.copy()
    length[::7] = np.nan  # a loop that misses a length now and then
    gappy = Detections.from_columns(
        d.position, d.velocity, d.timestamp, target=d.target, lane=d.lane, length=length
    )
    anchor, _ = lane_queue_anchors(gappy)
    labels = d.target.astype(str)
    unmeasured = np.flatnonzero(np.isnan(length) & (anchor >= 0))
    assert unmeasured.size >= 0.5 * np.count_nonzero(np.isnan(length) & (d.position > 0))
    assert np.mean(labels[anchor[unmeasured]] == labels[unmeasured]) >= 0.95


def test_anchors_lift_assignment_in_a_queue() -> None:
    d = lane_queue(seed=2)
    anchored = associate(d, "assignment").metrics
    alone = associate(d, "assignment", {"lane_anchors": False}).metrics
    assert anchored is not None and alone is not None
    # Travel times 10-25 headways long: speeds and times alone cannot tell neighbours apart.
    assert anchored.accuracy >= 0.95
    assert anchored.accuracy > alone.accuracy + 0.05


def test_track_lengths_average_the_readings_up_to_and_from_each_detection() -> None:
    # One vehicle past four sensors (the third reads no length), another past two, and a
    # detection in no track.
    d = Detections.from_columns(
        [0.0, 100.0, 200.0, 300.0, 0.0, 100.0, 200.0],
        [20.0] * 7,
        [0.0, 5.0, 10.0, 15.0, 1.0, 6.0, 11.0],
        lane=[0] * 7,
        length=[4.0, 4.4, None, 3.6, 12.0, 13.0, 9.0],
    )
    s = arrange(d, AssignmentParams())
    track = np.array([0, 0, 0, 0, 1, 1, -1])
    before, before_count, after, after_count = track_lengths(s, track)
    log = np.log(d.length)
    np.testing.assert_array_equal(before_count, [1, 2, 2, 3, 1, 2, 1])
    np.testing.assert_array_equal(after_count, [3, 2, 1, 1, 2, 1, 1])
    np.testing.assert_allclose(
        before[[1, 3, 5]], [log[:2].mean(), log[[0, 1, 3]].mean(), log[4:6].mean()]
    )
    np.testing.assert_allclose(after[[0, 2, 4]], [log[[0, 1, 3]].mean(), log[3], log[4:6].mean()])
    # Outside any track, and without tracks, a detection's own reading alone.
    assert before[6] == after[6] == log[6]
    alone = track_lengths(s, None)
    np.testing.assert_allclose(alone[0][[0, 1, 3]], log[[0, 1, 3]])
    np.testing.assert_array_equal(alone[1], np.isfinite(log))


@pytest.mark.parametrize(
    ("name", "single", "tracked"),
    # Share of anchors right, as measured: with each pair's two readings, and with the
    # lengths averaged along the true tracks (with the kinematic term centred on each block's
    # own chain, stop-and-go gains less from the averages: 0.957 -> 0.966, 0.973 before; with
    # skips costed by the segments' lane changes, the bottleneck's first chains 0.924 -> 0.931).
    [("sumo-bottleneck", 0.931, 0.975), ("sumo-stopgo", 0.957, 0.966)],
)
def test_lengths_averaged_along_tracks_pin_chains_that_single_readings_cannot(
    name: str, single: float, tracked: float
) -> None:
    d = read_detections_csv((SUMO_FEATURES / f"{name}.csv").read_bytes())
    params = AssignmentParams()
    s = arrange(d, params)
    model = segment_prior(s, params.max_skip + 1, params)
    labels = d.target.astype(str)
    track = np.where(labels == "clutter", -1, np.unique(labels, return_inverse=True)[1])

    def right(chains: anchors.Chains) -> float:
        anchored = np.flatnonzero(chains.predecessor >= 0)
        return float(np.mean(labels[chains.predecessor[anchored]] == labels[anchored]))

    first = lane_order_anchors(s, model, params)
    assert right(first) == pytest.approx(single, abs=0.005)
    redrawn = lane_order_anchors(s, model, params, track, first)
    assert right(redrawn) >= tracked - 0.005
    assert right(redrawn) >= right(first) + 0.008
    # Drawn again, a segment keeps the smoothness it learned; only the segments named are drawn.
    np.testing.assert_array_equal(redrawn.smoothness, first.smoothness)
    some = lane_order_anchors(s, model, params, track, first, segments=[2])
    assert set(s.sensor[some.predecessor[some.predecessor >= 0]]) == {2}


def test_chains_drawn_in_small_runs_are_the_chains_drawn_at_once(monkeypatch) -> None:
    # The programme draws many blocks at once (`first_chains.batches`); how many must change
    # nothing, from one block a run (and one segment a group) to all of them. Blocks of 40 make
    # many.
    d = read_detections_csv((SUMO_FEATURES / "sumo-bottleneck.csv").read_bytes())
    params = AssignmentParams()
    s = arrange(d, params)
    model = segment_prior(s, params.max_skip + 1, params)
    monkeypatch.setattr(anchors, "BLOCK", 40)
    drawn = []
    for budget in (1, 20_000, 10**9):
        monkeypatch.setattr(first_chains, "BATCH_PAIRS", budget)
        drawn.append(lane_order_anchors(s, model, params))
    assert np.mean(drawn[0].predecessor >= 0) > 0.5
    for chains in drawn[1:]:
        np.testing.assert_array_equal(chains.predecessor, drawn[0].predecessor)
        np.testing.assert_array_equal(chains.margin, drawn[0].margin)
        np.testing.assert_array_equal(chains.smoothness, drawn[0].smoothness)


def test_where_a_lane_drop_renumbers_the_lanes_each_lane_is_chained_to_the_lane_it_reaches(
    monkeypatch,
) -> None:
    # SUMO's val-lanedrop2 (seed 0, with lane, length and class): two lanes narrowing to one at
    # 2.3-2.8 km. The last sensor but one, inside the narrow stretch, reports its one lane as
    # lane 1; the last, where the road is wide again, numbers its two lanes from 0, and 94 of
    # the last segment's 127 vehicles go from lane 1 to lane 0. Chained by lane number, that
    # segment had 23 keepers to align, and 7 % of its links were right.
    d = read_detections_csv((SUMO_FEATURES / "val-lanedrop2.csv").read_bytes())
    params = AssignmentParams()
    s = arrange(d, params)
    labels = d.target.astype(str)
    truth = np.where(labels == "clutter", -1, np.unique(labels, return_inverse=True)[1])
    prior = segment_prior(s, params.max_skip + 1, params)
    model = learn_segments(s, truth, params, prior)
    last = s.positions.size - 2
    assert lane_destinations(s, model, last)[1] == 0
    # Elsewhere the lanes keep their numbers.
    assert lane_destinations(s, model, 1) == {0: 0, 1: 1}
    measured = associate(d, "assignment").metrics
    monkeypatch.setattr(
        anchors,
        "lane_destinations",
        lambda s, model, k: {lane: lane for lane in np.unique(s.features.lane[s.members(k)])},
    )
    by_number = associate(d, "assignment").metrics
    assert measured is not None and by_number is not None
    # As measured: 93.9 % against 87.9 % with every lane chained to its own number.
    assert measured.accuracy >= 0.93
    assert measured.accuracy >= by_number.accuracy + 0.04


def _model_of_the_true_tracks(name: str):
    d = read_detections_csv((SUMO_FEATURES / f"{name}.csv").read_bytes())
    params = AssignmentParams()
    s = arrange(d, params)
    labels = d.target.astype(str)
    truth = np.where(labels == "clutter", -1, np.unique(labels, return_inverse=True)[1])
    return d, s, learn_segments(s, truth, params, segment_prior(s, params.max_skip + 1, params))


def _lane_skip_costs(s, model, k: int, lane: int, destination: int) -> tuple[float, float]:
    up, down = s.members(k), s.members(k + 1)
    lanes = s.features.lane
    return skip_costs(s, model, k, up[lanes[up] == lane], down[lanes[down] == destination])


def test_a_skip_in_a_lanes_chain_costs_what_the_segments_lane_changes_say() -> None:
    # SUMO's bottleneck (seed 0, with lane, length and class): lanes 1 and 2 merge into lane 0
    # over segment 7, and one lane runs on over segment 8.
    _, s, model = _model_of_the_true_tracks("sumo-bottleneck")
    assert lane_destinations(s, model, 7) == {1: 0, 2: 0}
    least, most = (-np.log(chance) for chance in reversed(SKIP_CHANCES))
    # One lane running on: no vehicle leaves it or joins it, a skip costs the most.
    assert _lane_skip_costs(s, model, 8, 0, 0) == pytest.approx((most, most))
    # The merge: every vehicle of lane 1 reaches lane 0 (a skipped row costs the most), and
    # most of lane 0's arrivals come from lane 2 (a skipped column in lane 1's chain costs the
    # least), where a fixed cost charged each of them as a lane changer.
    row, column = _lane_skip_costs(s, model, 7, 1, 0)
    assert row == pytest.approx(most) and column == pytest.approx(least)
    assert column < SKIP < row


def test_learned_skips_keep_a_bottlenecks_chains_from_slipping(monkeypatch) -> None:
    d = read_detections_csv((SUMO_FEATURES / "sumo-bottleneck.csv").read_bytes())
    learned = associate(d, "assignment").metrics
    monkeypatch.setattr(anchors, "skip_costs", lambda *args: (SKIP, SKIP))
    fixed = associate(d, "assignment").metrics
    assert learned is not None and fixed is not None
    # As measured: 92.9 % against 88.7 % with every skip at the one cost.
    assert learned.accuracy >= 0.91
    assert learned.accuracy >= fixed.accuracy + 0.025
