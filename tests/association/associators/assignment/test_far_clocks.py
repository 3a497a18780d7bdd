"""Sensors whose clocks are minutes or hours off (`assignment/far_clocks.py`): found from the
cross-correlation of each segment's detections at any lag, at either end of the road too, and
set right before the fine search; never on the committed cases on time."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.far_clocks import (
    FAR_LEAST,
    FAR_LEAST_TRAVEL_TIMES,
    FarRoad,
    Lag,
    far_offsets,
    sensor_offset,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate

SUMO = Path(__file__).parents[3] / "data" / "sumo"
FEATURES = Path(__file__).parents[3] / "data" / "sumo-features"
PARAMS = AssignmentParams()


def off(d: Detections, seconds: dict[int, float]) -> Detections:
    """`d` as reported where sensor k's clock runs `seconds[k]` late."""
    positions = np.unique(d.position)
    late = np.zeros(len(d))
    for k, s in seconds.items():
        late[d.position == positions[k]] = s
    return dataclasses.replace(d, timestamp=d.timestamp + late)


def same_partition(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two groupings put the same detections together, whatever their groups' names."""
    pairs = np.unique(np.stack([a, b]), axis=1).shape[1]
    return pairs == np.unique(a).size == np.unique(b).size


def offsets_of(d: Detections) -> np.ndarray:
    offsets = arrange(d.without_labels(), PARAMS).clock_offsets
    assert offsets is not None
    return offsets


@pytest.mark.parametrize(
    ("sensor", "seconds"),
    [(5, 3600.0), (5, -3600.0), (5, 120.0), (0, 3600.0), (10, 3600.0), (10, -300.0), (0, 90.0)],
)
def test_a_clock_an_hour_or_minutes_off_is_set_right_anywhere_on_the_road(sensor, seconds):
    # A time zone or daylight saving time set wrongly (an hour), a clock set by hand (minutes):
    # beyond the fine search's minute, and at either end of the road, where no mirror tells.
    on_time = read_detections_csv(SUMO / "sumo-dense.csv")
    offsets = offsets_of(off(on_time, {sensor: seconds}))
    assert abs(offsets[sensor] - seconds) < 1.0
    assert np.all(np.delete(offsets, sensor) == 0.0)


@pytest.mark.parametrize("case", ["sumo-freeflow", "sumo-dense", "sumo-junctions"])
def test_traffic_past_a_clock_an_hour_late_is_grouped_as_on_time(case):
    # Before, the sensor's detections were left alone or linked to other vehicles: free flow
    # 90.6 / 88.7 % with the first / last sensor an hour late, dense 86.9 / 85.5 %, against
    # 99.2 and 95.4 % on time.
    on_time = read_detections_csv(SUMO / f"{case}.csv")
    expected = associate(on_time)
    for sensor in (0, 5, -1):
        k = sensor % np.unique(on_time.position).size
        result = associate(off(on_time, {k: 3600.0}))
        assert same_partition(result.groups, expected.groups)
        assert any("3600.0 s later" in warning for warning in result.warnings)


@pytest.mark.parametrize("case", sorted(p.stem for p in SUMO.glob("*.csv")))
def test_clocks_on_time_are_not_taken_for_far_ones(case):
    """Queues, traffic lights, junctions and faults: no segment's correlation peaks far."""
    assert np.all(offsets_of(read_detections_csv(SUMO / f"{case}.csv")) == 0.0)


@pytest.mark.parametrize("case", sorted(p.stem for p in FEATURES.glob("*.csv")))
def test_clocks_on_time_with_features_are_not_taken_for_far_ones(case):
    assert np.all(offsets_of(read_detections_csv(FEATURES / f"{case}.csv")) == 0.0)


def test_a_segments_lag_is_its_far_clocks_offset_past_the_kinematic_travel_time():
    d = off(read_detections_csv(SUMO / "sumo-freeflow.csv"), {3: 3600.0})
    s = arrange(d.without_labels(), PARAMS)
    times = [d.timestamp[s.members(k)] for k in range(s.positions.size)]
    speeds = [s.speed[s.members(k)] for k in range(s.positions.size)]
    road = FarRoad(s.positions, times, speeds, np.array([np.median(v) for v in speeds]))
    into, out_of, beside = (road.lag(k) for k in (2, 3, 0))
    assert into is not None and out_of is not None and beside is not None
    assert abs(into.seconds - 3600.0) < 2.0 and abs(out_of.seconds + 3600.0) < 2.0
    assert abs(beside.seconds) < 2.0
    assert far_offsets(s.positions, times, speeds)[3] == pytest.approx(3600.0, abs=1.0)


def test_a_far_lag_that_does_not_mirror_or_that_both_ends_show_is_no_clock():
    def lag(seconds: float, typical: float = 10.0, flowing: bool = True) -> Lag:
        return Lag(seconds, 0.5, typical, flowing)

    # Into sensor 1 an hour more, out of it nothing: a lag of the road, not a clock.
    assert sensor_offset([lag(3600.0), lag(0.0), lag(0.0)], 1) is None
    # The first segment's far lag is sensor 1's where the next mirrors it, not sensor 0's.
    mirrored = [lag(3600.0), lag(-3600.0), lag(0.0)]
    assert sensor_offset(mirrored, 1) == 3600.0
    assert sensor_offset(mirrored, 0) is None
    assert sensor_offset([lag(-3600.0), lag(0.0)], 0) == 3600.0
    assert sensor_offset([lag(0.0), lag(-300.0)], 2) == -300.0
    assert sensor_offset([None, lag(0.0)], 0) is None
    # An end segment's far lag counts only where traffic flows alike at its two sensors, and
    # beside a segment that clearly keeps time (a queue's waves: a travel time short).
    assert sensor_offset([lag(-3600.0), None], 0) is None
    assert sensor_offset([lag(-3600.0, flowing=False), lag(0.0)], 0) is None
    assert sensor_offset([lag(-3600.0), lag(-10.0)], 0) is None
    assert sensor_offset([lag(-3600.0), lag(-4.0)], 0) == 3600.0
    # Within the fine search's minute, or two travel times (a crawl's waves): not far.
    assert sensor_offset([lag(-50.0), lag(0.0)], 0) is None
    assert sensor_offset([lag(125.0, typical=125.0), lag(-125.0, typical=125.0)], 1) is None
    assert sensor_offset([lag(300.0, typical=125.0), lag(-300.0, typical=125.0)], 1) == 300.0
    assert FAR_LEAST == 60.0 and FAR_LEAST_TRAVEL_TIMES == 2.0


def test_two_sensors_cannot_tell_whose_clock_is_off_and_a_paper_size_batch_is_not_searched():
    d = read_detections_csv(SUMO / "sumo-freeflow.csv")
    positions = np.unique(d.position)
    two = off(d.take(np.flatnonzero(d.position <= positions[1])), {1: 3600.0})
    assert np.all(offsets_of(two) == 0.0)
    assert np.all(offsets_of(simulate(preset("large"), seed=0).detections) == 0.0)
