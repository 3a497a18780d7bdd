"""Algorithm 1's optional detector features: lanes, lengths and classes, off by default."""

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.detections import CLUTTER
from roadlink.simulation import preset, simulate
from roadlink.simulation.vehicles import VEHICLE_CLASSES

# The CSVs these settings wrote before features existed (their sha256 at commit ba7547c, on
# that machine): the paper's presets, with and without faults, must stay what they were,
# random stream and all. Numbers are compared to a few ulps, not byte for byte: numpy's exp
# and log take the fastest instructions a CPU has (AVX-512 or AVX2), whose last bit may differ.
FAULTS = {
    "miss_probability": 0.05,
    "false_alarm_rate": 0.05,
    "duplicate_probability": 0.05,
    "velocity_noise": 0.02,
    "timestamp_noise": 0.05,
}
PRESETS = Path(__file__).parents[1] / "data" / "presets"
BEFORE_FEATURES = [
    ("large", 1, {}, "large-seed1.csv"),
    ("small", 2, FAULTS, "small-seed2-faults.csv"),
    ("congested", 0, FAULTS, "congested-seed0-faults.csv"),
]

TWO_SENSORS = {"sensor_positions": [0.0, 100.0]}


@pytest.mark.parametrize(("name", "seed", "overrides", "before"), BEFORE_FEATURES)
def test_without_features_the_output_is_what_it_was_before(name, seed, overrides, before):
    now = simulate(preset(name, **overrides), seed=seed).detections
    then = read_detections_csv((PRESETS / before).read_text())
    assert now.features == ()
    assert list(now.detection_id) == list(then.detection_id)
    assert list(now.sensor_id) == list(then.sensor_id)
    assert list(now.target) == list(then.target)
    for column in ("position", "velocity", "timestamp"):
        np.testing.assert_allclose(getattr(now, column), getattr(then, column), rtol=1e-13)


def test_features_are_off_by_default_and_leave_the_traffic_as_it_was():
    plain = simulate(preset("small"), seed=4).detections
    assert plain.features == ()
    rich = simulate(
        preset("small", lanes=3, vehicle_lengths=True, vehicle_classes=True), seed=4
    ).detections
    assert rich.features == ("lane", "length", "vehicle_class")
    # Drawn from a stream of their own: the same vehicles pass at the same times and speeds.
    assert write_detections_csv(rich.without_features()) == write_detections_csv(plain)


def lanes_by_target(d):
    """Each target's lane at every sensor, in road order (targets x sensors)."""
    labels = d.target.astype(str)
    rows = []
    for t in np.unique(labels):
        mine = np.flatnonzero(labels == t)
        rows.append(d.lane[mine[np.argsort(d.position[mine])]])
    return np.array(rows)


def test_lanes_start_uniform_and_change_to_a_neighbour_at_the_stated_rate():
    config = preset("large", n_targets=3000, velocity_model="constant", lanes=3)
    config = config.model_copy(update={"lane_change_probability": 0.2})
    lanes = lanes_by_target(simulate(config, seed=5).detections)
    assert lanes.shape == (3000, 10) and set(np.unique(lanes)) == {0, 1, 2}
    np.testing.assert_allclose(np.bincount(lanes[:, 0]) / 3000, [1 / 3] * 3, atol=0.03)
    steps = np.diff(lanes, axis=1)
    # 27,000 segments: the rate's standard error is 0.0024.
    assert abs(np.mean(steps != 0) - 0.2) < 0.01
    assert set(np.unique(np.abs(steps))) == {0, 1}, "a change is to a neighbouring lane"


@pytest.mark.parametrize(("lanes", "change"), [(1, 0.5), (4, 0.0)])
def test_one_lane_or_no_changes_keep_every_vehicle_in_its_lane(lanes, change):
    config = preset("medium", n_targets=200, lanes=lanes, lane_change_probability=change)
    found = lanes_by_target(simulate(config, seed=1).detections)
    assert np.all(found == found[:, :1])
    assert found.max() == lanes - 1


def test_classes_come_in_the_stated_mix_each_with_its_range_of_lengths():
    config = preset(
        "large", n_targets=6000, vehicle_lengths=True, vehicle_classes=True, **TWO_SENSORS
    )
    d = simulate(config, seed=3).detections
    first = d.position == 0.0
    classes, lengths = d.vehicle_class[first].astype(str), d.length[first]
    for kind in VEHICLE_CLASSES:
        mine = classes == kind.name
        # Binomial standard error at 6,000 vehicles: 0.005 for cars, 0.002 for buses.
        assert abs(np.mean(mine) - kind.share) < 0.015, kind.name
        lo, hi = kind.length_range
        assert lo <= lengths[mine].min() and lengths[mine].max() <= hi
        # Uniform in the range: its mean is the middle.
        assert abs(lengths[mine].mean() - (lo + hi) / 2) < 0.08 * (hi - lo), kind.name
    assert set(classes) == {c.name for c in VEHICLE_CLASSES}


def test_a_vehicles_length_and_class_stay_with_it_along_the_road():
    config = preset("small", n_targets=50, vehicle_lengths=True, vehicle_classes=True)
    d = simulate(config, seed=8).detections
    for t in np.unique(d.target.astype(str)):
        mine = d.target == t
        assert np.ptp(d.length[mine]) == 0
        assert len(set(d.vehicle_class[mine])) == 1


def test_lengths_are_measured_with_the_configured_multiplicative_noise():
    settings = {"n_targets": 4000, "vehicle_lengths": True, **TWO_SENSORS}
    true = simulate(preset("large", **settings), seed=6).detections
    measured = simulate(preset("large", length_noise=0.08, **settings), seed=6).detections
    # Length noise moves no time: the rows are the same passages in the same order.
    assert measured.target.tolist() == true.target.tolist()
    ratio = np.log(measured.length / true.length)
    assert abs(ratio.std() - 0.08) < 0.004 and abs(ratio.mean()) < 0.004


def test_classes_alone_report_no_length_and_lengths_alone_no_class():
    only_classes = simulate(preset("small", vehicle_classes=True), seed=0).detections
    assert only_classes.features == ("vehicle_class",)
    only_lengths = simulate(preset("small", vehicle_lengths=True), seed=0).detections
    assert only_lengths.features == ("length",)


def test_false_alarms_and_duplicates_report_features_too():
    config = preset(
        "medium",
        n_targets=100,
        lanes=2,
        vehicle_lengths=True,
        false_alarm_rate=0.1,
        duplicate_probability=0.1,
    )
    d = simulate(config, seed=2).detections
    assert (d.target == CLUTTER).any()
    assert d.has_lane.all() and d.has_length.all()


@pytest.mark.parametrize(
    ("overrides", "field", "message"),
    [
        ({"lanes": 0}, "lanes", "greater than or equal to 1"),
        ({"lanes": 257}, "lanes", "less than or equal to 256"),
        ({"lanes": 2, "lane_change_probability": 1.5}, "lane_change_probability", "less than"),
        ({"lane_change_probability": 0.3}, "lane_change_probability", "needs lanes"),
        ({"length_noise": 0.05}, "length_noise", "needs vehicle_lengths"),
        ({"vehicle_lengths": True, "length_noise": -0.1}, "length_noise", "greater than or"),
        ({"vehicle_lengths": "sometimes"}, "vehicle_lengths", "valid boolean"),
    ],
)
def test_invalid_feature_settings_are_refused_naming_the_field(overrides, field, message):
    with pytest.raises(ValidationError) as refused:
        preset("large", **overrides)
    [error] = refused.value.errors()
    assert error["loc"] == (field,) and message in error["msg"]
