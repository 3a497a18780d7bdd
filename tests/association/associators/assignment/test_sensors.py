"""The detections arranged by sensor (`assignment/sensors.py`), and the kinematic travel time."""

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.sensors import (
    KINEMATIC_SKEW,
    arrange,
    one_speed_warnings,
    travel_time,
)
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import sensor_cut


def test_the_kinematic_travel_time_weighs_both_ends_speeds_alike():
    assert KINEMATIC_SKEW == 0.5
    assert travel_time(100.0, 10.0, 20.0) == pytest.approx(100.0 * (0.5 / 10.0 + 0.5 / 20.0))
    assert travel_time(100.0, 10.0, 20.0, skew=0.0) == pytest.approx(10.0)
    assert travel_time(100.0, 10.0, 20.0, skew=1.0) == pytest.approx(5.0)
    lengths = np.array([100.0, 200.0])
    np.testing.assert_allclose(travel_time(lengths, 10.0, 10.0), [10.0, 20.0])


def test_detections_are_ordered_by_sensor_then_time_with_speeds_floored():
    d = Detections.from_columns(
        position=[100.0, 0.0, 0.0, 100.0, 0.0],
        velocity=[20.0, 30.0, 0.001, 25.0, 20.0],
        timestamp=[9.0, 3.0, 1.0, 5.0, 2.0],
    )
    params = AssignmentParams()
    s = arrange(d, params)
    assert s.positions.tolist() == [0.0, 100.0]
    assert s.order.tolist() == [2, 4, 1, 3, 0]
    assert s.start.tolist() == [0, 3, 5]
    assert s.members(1).tolist() == [3, 0]
    assert s.sensor.tolist() == [1, 0, 0, 1, 0]
    floor = params.velocity_floor * 20.0  # the median speed
    assert s.speed[2] == floor and s.speed[0] == 20.0
    assert s.top_speed.tolist() == [30.0, 25.0]
    assert s.median_speed.tolist() == [20.0, 22.5]
    np.testing.assert_allclose(s.sorted_inverse_speed, 1.0 / s.speed[s.order])
    # A speed relative to its own sensor's median log speed.
    assert s.relative_speed[1] == pytest.approx(np.log(30.0) - np.log(20.0))


def test_the_typical_travel_time_is_between_neighbours_at_their_median_speeds():
    d = Detections.from_columns([0.0, 100.0, 300.0], [10.0, 10.0, 20.0], [0.0, 10.0, 25.0])
    s = arrange(d, AssignmentParams())
    # 100 m at 10 m/s both ends, 200 m at 10 then 20 m/s: 10 s and 15 s, median 12.5 s.
    assert s.typical_travel_time() == pytest.approx(12.5)
    one = arrange(Detections.from_columns([0.0], [10.0], [0.0]), AssignmentParams())
    assert one.typical_travel_time() is None


def test_detections_by_track_are_in_lexsorts_order():
    rng = np.random.default_rng(2)
    n_sensors, n_tracks = 7, 40
    # Each track holds at most one detection per sensor.
    cells = rng.choice(n_sensors * n_tracks, size=150, replace=False)
    sensor, track_of = cells % n_sensors, cells // n_sensors
    detections = Detections.from_columns(
        position=100.0 * sensor,
        velocity=np.full(cells.size, 30.0),
        timestamp=rng.random(cells.size),
    )
    s = arrange(detections, AssignmentParams())
    track = np.where(rng.random(cells.size) < 0.8, track_of, -1)
    assigned = np.flatnonzero(track >= 0)
    expected = assigned[np.lexsort((s.sensor[assigned], track[assigned]))]
    assert np.array_equal(s.by_track(assigned, track), expected)


@pytest.mark.parametrize("reach", [1, 2, 3, 7])
def test_every_detection_reaching_the_sensors_after_it_is_by_sensor_then_order(reach: int):
    # The order of one lexsort by (sensor reached, place in `order`), to the element.
    rng = np.random.default_rng(4)
    d = Detections.from_columns(
        position=rng.choice([0.0, 100.0, 250.0, 300.0, 420.0], 60),
        velocity=rng.uniform(15.0, 35.0, 60),
        timestamp=rng.uniform(0.0, 100.0, 60),
    )
    s = arrange(d, AssignmentParams())
    n = s.time.size
    a = np.tile(s.order, reach)
    q = s.sensor[a] + np.repeat(np.arange(1, reach + 1), n)
    by = np.lexsort((np.tile(np.arange(n), reach), q))
    by = by[q[by] < s.positions.size]
    found_a, found_q = s.reaching(reach)
    assert np.array_equal(found_a, a[by]) and np.array_equal(found_q, q[by])


def test_arrival_keys_sort_as_sensor_then_time_and_none_with_a_nan_time():
    d = Detections.from_columns(
        position=[0.0, 0.0, 100.0, 100.0],
        velocity=[20.0] * 4,
        timestamp=[3.0, 1.0, 2.0, 0.5],
    )
    s = arrange(d, AssignmentParams())
    keys = s.arrival_keys
    assert keys is not None
    assert np.array_equal(np.sort(keys), keys)
    assert np.array_equal(keys.real, [0, 0, 1, 1]) and np.array_equal(keys.imag, [1, 3, 0.5, 2])
    s = arrange(d, AssignmentParams())
    s.sorted_time[0] = np.nan
    assert s.arrival_keys is None


def test_a_sensor_that_reports_one_speed_for_every_vehicle_is_named(caplog):
    """A loop that counts and fills in a default speed tells vehicles nothing apart by it."""
    d = simulate(preset("congested"), seed=0).detections
    third = d.position == np.unique(d.position)[2]
    stuck = Detections.from_columns(
        d.position, np.where(third, 25.0, d.velocity), d.timestamp, target=list(d.target)
    )
    s = arrange(stuck, AssignmentParams())
    assert s.reads_one_speed.tolist() == [k == 2 for k in range(s.positions.size)]
    # Its median tells nothing of its calibration (`weak_bias.calibration_biases`).
    assert np.isnan(s.calibration_speed[2]) and np.isfinite(np.delete(s.calibration_speed, 2)).all()
    assert one_speed_warnings(s) == [
        f"the sensor at position {np.unique(d.position)[2]:g} reports one speed (25) for every "
        "vehicle: its speeds tell vehicles nothing apart (a loop that counts and fills in a "
        "default, or a stuck reading?)"
    ]
    assert associate(stuck, "assignment").warnings == tuple(one_speed_warnings(s))
    assert "reports one speed" in caplog.text
    # Every reading under the floor is a standing queue, not one reading; and a sensor with
    # speeds to tell is not named.
    crawl = Detections.from_columns(
        d.position, np.where(third, 0.01, d.velocity), d.timestamp, target=list(d.target)
    )
    assert one_speed_warnings(arrange(crawl, AssignmentParams())) == []
    assert one_speed_warnings(arrange(d, AssignmentParams())) == []


def counts_road(counts: list[int]) -> Detections:
    """Sensors 200 m apart, each with its count of detections one second apart at 20 m/s."""
    position = np.repeat(200.0 * np.arange(len(counts)), counts)
    time = np.concatenate([np.arange(n, dtype=np.float64) for n in counts])
    return Detections.from_columns(position, np.full(position.size, 20.0), time)


@pytest.mark.parametrize(
    ("counts", "sparse"),
    [
        ([60, 25, 60, 60], [False, True, False, False]),  # quiet after 25 of a busy batch
        ([60, 60, 60, 10], [False, False, False, True]),  # the last sensor, started late
        ([41, 38, 41, 40], [False, False, False, False]),  # a few misses more than its neighbour
        ([30, 10, 30, 30], [False, False, False, False]),  # a paper-size batch: few everywhere
    ],
)
def test_a_sensor_far_quieter_than_a_busy_neighbour_is_sparse(counts, sparse):
    s = arrange(counts_road(counts), AssignmentParams())
    assert s.sparse.tolist() == sparse


def test_a_sparse_sensors_typical_speed_is_its_neighbours():
    # Congested traffic at 20-40 m/s; the sensor at 300 m keeps its first 15 reports, those of
    # the fastest vehicles, which reach it first.
    d = simulate(preset("congested", slow_zone=None), seed=0).detections
    s = arrange(sensor_cut(d, 3, 15), AssignmentParams())
    assert s.sparse.tolist() == [k == 3 for k in range(s.positions.size)]
    assert s.median_speed[3] > 1.1 * max(s.median_speed[2], s.median_speed[4])
    assert s.typical_speed[3] == pytest.approx(0.5 * (s.median_speed[2] + s.median_speed[4]))
    np.testing.assert_array_equal(np.delete(s.typical_speed, 3), np.delete(s.median_speed, 3))


def stamped(timestamps: list[float], positions: list[float] | None = None) -> Detections:
    """Detections at these times, at 0 and 100 m (or `positions`), each of its own speed."""
    n = len(timestamps)
    return Detections.from_columns(
        position=positions or [0.0] * (n // 2) + [100.0] * (n - n // 2),
        velocity=np.linspace(19.0, 21.0, n),
        timestamp=timestamps,
    )


@pytest.mark.parametrize(
    ("timestamps", "step"),
    [
        ([3.0, 1.0, 1.0, 7.0, 5.0, 6.0], 1.0),  # whole seconds
        ([10.3, 10.1, 10.9, 15.5, 15.7, 16.7], pytest.approx(0.2)),  # fifths, off whole ones
        ([0.0, 1.5, 3.0, 1e9, 1e9 + 1.5, 1e9 + 4.5], 1.5),  # epoch seconds, each sensor its own
        ([0.0, 1.3, 2.9, 5.0, 6.1, 7.2], 0.0),  # not one step
        ([1.0, 1.0, 1.0, 2.0, 2.0, 2.0], 0.0),  # no two distinct times at one sensor
    ],
)
def test_the_step_times_are_stamped_in_is_the_least_gap_every_time_falls_on(timestamps, step):
    assert arrange(stamped(timestamps), AssignmentParams()).time_step == step


def test_times_stamped_coarsely_are_spread_within_their_step_and_sorted_again():
    rng = np.random.default_rng(0)
    start = np.sort(rng.uniform(0.0, 100.0, 50))
    exact: np.ndarray = np.r_[start, start + 2.5]  # 50 m at 20 m/s: 2.5 s
    d = stamped(list(map(float, np.round(exact))), [0.0] * 50 + [50.0] * 50)
    s = arrange(d, AssignmentParams())
    # Steps under a share of the shortest segment's travel time (here 2.5 s) are left alone.
    assert s.within_step(0.5) is s
    spread = s.within_step(0.25)
    assert np.abs(spread.time - s.time).max() <= 0.5
    assert np.unique(spread.time).size == spread.time.size
    for k in range(2):
        assert (np.diff(spread.sorted_time[spread.start[k] : spread.start[k + 1]]) > 0).all()
    np.testing.assert_array_equal(spread.time[spread.order], spread.sorted_time)
    np.testing.assert_array_equal(spread.sensor[spread.order], s.sensor[s.order])
    # The same draws for the same detections, whatever their input order.
    shuffled = rng.permutation(len(d))
    again = arrange(d.take(shuffled), AssignmentParams()).within_step(0.25)
    np.testing.assert_array_equal(again.time, spread.time[shuffled])
