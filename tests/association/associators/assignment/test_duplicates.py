"""A passage reported twice (`assignment/duplicates.py`): which report may copy which, and the
copy joining its twin's target."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.duplicates import (
    duplicate_followers,
    join_duplicates,
    repeat_of,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import steady_vehicles

COMMITTED_SUMO = Path(__file__).parents[3] / "data" / "sumo"


def test_a_report_moments_after_one_of_the_same_speed_may_duplicate_it():
    d = Detections.from_columns(
        position=[0.0, 0.0, 0.0, 0.0, 100.0],
        velocity=[20.0, 20.5, 30.0, 20.0, 20.0],
        timestamp=[0.0, 0.2, 0.3, 5.0, 5.0],
    )
    params = AssignmentParams(duplicate_window=0.5, duplicate_velocity_tolerance=0.05)
    # Row 1 copies row 0 (0.2 s later, 2.5 % faster); row 2 is too fast to be a copy; row 3
    # comes too late; row 4 is alone at its sensor.
    assert duplicate_followers(arrange(d, params), params).tolist() == [-1, 0, -1, -1, -1]
    off = AssignmentParams(duplicate_window=0.0)
    assert duplicate_followers(arrange(d, off), off).tolist() == [-1] * 5


@pytest.mark.parametrize("window", [0.5, 5.0, 60.0])
@pytest.mark.parametrize("name", ["medium", "congested"])
def test_the_reports_each_may_duplicate_are_each_sensors_own_lag_by_lag(
    window: float, name: str
) -> None:
    # Every sensor's reports at once, lag after lag (few reports a sensor), or sensor by sensor
    # (the congested preset's many): the leaders found report by report, in time order, each
    # the nearest earlier alike report, or where that is a copy, its root passage if that is
    # close and alike too.
    params = AssignmentParams(duplicate_window=window, duplicate_velocity_tolerance=0.3)
    d = simulate(preset(name, duplicate_probability=0.3, false_alarm_rate=0.1), seed=3)
    s = arrange(d.detections, params)
    leader = np.full(s.time.size, -1, dtype=np.int64)
    tolerance = np.log1p(params.duplicate_velocity_tolerance)

    def alike(i: int, j: int) -> bool:
        return bool(
            s.time[i] - s.time[j] <= params.duplicate_window
            and abs(s.log_speed[i] - s.log_speed[j]) <= tolerance
        )

    for k in range(s.positions.size):
        m = s.members(k).tolist()
        for n, i in enumerate(m):
            nearest = next((j for j in reversed(m[:n]) if alike(i, j)), -1)
            if nearest >= 0 and leader[nearest] >= 0:
                root = int(leader[nearest])
                nearest = root if alike(i, root) else -1
            leader[i] = nearest
    found = duplicate_followers(s, params)
    assert (found >= 0).sum() > 3 and np.array_equal(found, leader)


def side_by_side(lane: list[int | None], vehicle_class: list[str | None]) -> Detections:
    # Two reports of one sensor 0.2 s apart at one speed, and a second sensor's.
    return Detections.from_columns(
        position=[0.0, 0.0, 100.0],
        velocity=[20.0, 20.2, 20.0],
        timestamp=[0.0, 0.2, 5.0],
        lane=[*lane, 0],
        vehicle_class=[*vehicle_class, "car"],
    )


@pytest.mark.parametrize(
    ("lane", "vehicle_class", "copy"),
    [
        ([0, 0], ["car", "car"], True),
        ([0, 1], ["car", "car"], False),  # the next lane: another vehicle
        ([0, 0], ["car", "truck"], False),  # another class: another vehicle
        ([0, None], [None, "car"], True),  # what one of them does not report says nothing
    ],
)
def test_a_copy_reads_the_same_lane_and_class(
    lane: list[int | None], vehicle_class: list[str | None], copy: bool
) -> None:
    params = AssignmentParams()
    leader = duplicate_followers(arrange(side_by_side(lane, vehicle_class), params), params)
    assert leader.tolist() == ([-1, 0, -1] if copy else [-1, -1, -1])


def test_a_copy_left_out_joins_its_twins_target_either_way_round() -> None:
    # Reports 1 and 2 copy 0; 4 copies 3; 6 copies 5; 8 copies 7.
    leader = np.array([-1, 0, 1, -1, 3, -1, 5, -1, 7])
    target = np.array([4, -1, -1, -1, 2, 0, 1, -1, -1])
    joined = join_duplicates(target, leader)
    # 1 and 2 join 0's target (2 through 1); 3, left out, joins its copy's; 5 and 6 are two
    # targets' and stay so; 7 and 8 are in none and stay out.
    assert joined.tolist() == [4, 4, 4, 2, 2, 0, 1, -1, -1]
    assert target.tolist() == [4, -1, -1, -1, 2, 0, 1, -1, -1]  # not changed in place


def test_a_leader_left_out_joins_the_first_of_its_copies_in_a_target() -> None:
    leader = np.array([-1, 0, 0])
    assert join_duplicates(np.array([-1, 3, 5]), leader).tolist() == [3, 3, 5]


def test_without_copies_the_targets_are_as_they_were() -> None:
    target = np.array([0, -1, 1])
    assert join_duplicates(target, np.full(3, -1)).tolist() == [0, -1, 1]


def test_a_copy_in_a_target_is_reported_beside_its_twin_without_a_link_of_its_own() -> None:
    d = simulate(preset("medium", duplicate_probability=0.1), seed=5).detections
    result = associate(d, "assignment")
    targets = result.to_dict()["targets"]
    with_copy = [
        t for t in targets if len({x["sensor_id"] for x in t["detections"]}) < len(t["detections"])
    ]
    assert with_copy
    for target in with_copy:
        rows = target["detections"]
        linked = [x["link_confidence"] for x in rows if "link_confidence" in x]
        # One link into each sensor but the first, whatever the copies; the target's confidence
        # is the product of those links alone.
        assert len(linked) == len({x["sensor_id"] for x in rows}) - 1
        assert target["confidence"] == pytest.approx(float(np.prod(linked)))
    # The matrix lists a copy beside its twin in one cell, its link confidence empty.
    cells = [line for line in result.to_matrix_csv().splitlines()[1:] if ";" in line]
    assert len(cells) == len(with_copy)


def test_speeds_below_the_floor_are_not_alike():
    """In a crawl every reading under `velocity_floor` of the median is floored to one speed:
    what the readings were is unknown, so two vehicles crawling past are not one passage."""
    d = Detections.from_columns(
        position=[0.0] * 4 + [100.0] * 4,
        velocity=[0.3, 0.5, 20.0, 20.0] + [20.0] * 4,
        timestamp=[0.0, 0.3, 10.0, 10.2, 20.0, 25.0, 30.0, 35.0],
    )
    params = AssignmentParams()
    s = arrange(d, params)
    assert s.speed[0] == s.speed[1] == s.speed_floor  # both floored to one speed
    assert duplicate_followers(s, params)[:4].tolist() == [-1, -1, -1, 2]


def test_a_copy_copies_a_passage_not_another_copy():
    """A detector stuck repeating one reading every 0.3 s (the window 0.5 s): each report
    within the window of the passage it copies pairs with it, and the next starts anew."""
    d = Detections.from_columns(
        position=[0.0] * 6 + [100.0],
        velocity=[20.0] * 7,
        timestamp=[0.0, 0.3, 0.6, 0.9, 1.2, 1.5, 30.0],
    )
    params = AssignmentParams(duplicate_window=0.5)
    s = arrange(d, params)
    assert duplicate_followers(s, params)[:6].tolist() == [-1, 0, -1, 2, -1, 4]
    # Three reports within the window of the first are all its copies.
    wider = AssignmentParams(duplicate_window=0.7)
    assert duplicate_followers(arrange(d, wider), wider)[:3].tolist() == [-1, 0, 0]


def test_a_batch_sent_twice_groups_as_the_batch_once():
    """A gateway that sends its batch again repeats every report exactly: each copy joins its
    vehicle's target, none is a vehicle of its own."""
    once = steady_vehicles([0.0, 2.0], [20.0, 25.0], [0.0, 100.0, 200.0, 300.0])
    twice = Detections.from_columns(
        position=np.tile(once.position, 2),
        velocity=np.tile(once.velocity, 2),
        timestamp=np.tile(once.timestamp, 2),
        target=list(once.target) * 2,
    )
    s = arrange(twice, AssignmentParams())
    repeats = repeat_of(s, twice)
    assert repeats is not None
    assert repeats.tolist() == list(range(len(once))) * 2
    result = associate(twice, "assignment")
    assert result.n_targets == 2 and result.metrics is not None
    assert result.metrics.accuracy == 1.0


def test_a_repeat_is_the_same_report_to_the_last_feature():
    # Rows 1 and 4 repeat row 0 (row 4 through a second feed, in another place of the input);
    # row 2 is the same passage in another lane, row 3 of another length, row 5 at another
    # sensor: each a report of its own.
    d = Detections.from_columns(
        position=[0.0, 0.0, 0.0, 0.0, 0.0, 100.0],
        velocity=[20.0, 20.0, 20.0, 20.0, 20.0, 20.0],
        timestamp=[1.0, 1.0, 1.0, 1.0, 1.0, 1.0],
        lane=[0, 0, 1, 0, 0, 0],
        length=[4.5, 4.5, 4.5, 4.6, 4.5, 4.5],
        vehicle_class=["car", "car", "car", "car", "car", "car"],
    )
    repeats = repeat_of(arrange(d, AssignmentParams()), d)
    assert repeats is not None and repeats.tolist() == [0, 0, 2, 3, 0, 5]
    assert (
        repeat_of(arrange(d.take([0, 2, 3, 5]), AssignmentParams()), d.take([0, 2, 3, 5])) is None
    )


@pytest.mark.parametrize("case", ["sumo-dense", "sumo-freeflow"])
def test_dense_traffic_sent_twice_groups_as_sent_once(case):
    # Every report twice (a gateway's retry with new ids, two feeds of the same detectors):
    # linked among the others, the repeats took neighbours' places in dense traffic (69.3 and
    # 92.4 %, against 95.4 and 99.2 % once), and were read as vehicles leaving and joining.
    once = read_detections_csv(COMMITTED_SUMO / f"{case}.csv")
    twice = once.take(np.r_[np.arange(len(once)), np.arange(len(once))])
    single, double = associate(once, "assignment"), associate(twice, "assignment")
    n = len(once)
    np.testing.assert_array_equal(double.groups[:n], single.groups)
    np.testing.assert_array_equal(double.groups[n:], single.groups)
    assert double.link_confidence is not None and single.link_confidence is not None
    np.testing.assert_array_equal(double.link_confidence[:n], single.link_confidence)
    assert np.isnan(double.link_confidence[n:]).all()


def stamped_coarsely(d: Detections) -> Detections:
    """`d` as detectors that stamp whole seconds and read whole km/h report it."""
    return replace(d, timestamp=np.round(d.timestamp), velocity=np.round(d.velocity * 3.6) / 3.6)


def test_vehicles_alike_by_chance_in_coarse_readings_are_not_repeats():
    # SUMO's dense traffic in whole seconds and km/h: 164 of 1,719 reports share a sensor, a
    # second and a speed with another, no more often than consecutive reports a second apart
    # share a speed. Read as repeats, each such vehicle took another's target.
    coarse = stamped_coarsely(read_detections_csv(COMMITTED_SUMO / "sumo-dense.csv"))
    s = arrange(coarse, AssignmentParams())
    o = s.order
    alike = (s.time[o[1:]] == s.time[o[:-1]]) & (coarse.velocity[o[1:]] == coarse.velocity[o[:-1]])
    assert np.count_nonzero(alike & (s.sensor[o[1:]] == s.sensor[o[:-1]])) > 50
    assert repeat_of(s, coarse) is None
    # Sent twice, the same coarse reports are repeats again, every one.
    twice = coarse.take(np.r_[np.arange(len(coarse)), np.arange(len(coarse))])
    repeats = repeat_of(arrange(twice, AssignmentParams()), twice)
    assert repeats is not None
    assert (repeats[len(coarse) :] != np.arange(len(coarse), len(twice))).all()
