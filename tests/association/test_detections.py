import dataclasses
import math

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators import AssociationError
from roadlink.association.detections import DetectionError, Detections, concatenate
from roadlink.association.feature_columns import CodedTexts, classes_in_order


def make(**overrides):
    columns = {
        "position": [0.0, 100.0, 0.0, 100.0],
        "velocity": [20.0, 21.0, 30.0, 29.0],
        "timestamp": [1.0, 6.0, 2.0, 5.5],
    }
    columns.update(overrides)
    return Detections.from_columns(**columns)


def problems_of(excinfo):
    return [(p.row, p.field) for p in excinfo.value.problems]


def test_generates_sensor_ids_by_road_order_and_detection_ids():
    d = make(position=[100.0, 0.0, 100.0, 0.0])
    assert d.sensor_id.tolist() == ["S2", "S1", "S2", "S1"]
    assert d.detection_id.tolist() == ["d1", "d2", "d3", "d4"]
    assert d.reference_position == 0.0
    assert d.target.tolist() == [None] * 4


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "nan", "inf"])
def test_non_finite_numbers_name_row_and_field(bad):
    with pytest.raises(DetectionError) as excinfo:
        make(timestamp=[1.0, bad, 2.0, 3.0])
    assert problems_of(excinfo) == [(2, "timestamp")]
    assert "row 2" in str(excinfo.value) and "timestamp" in str(excinfo.value)


@pytest.mark.parametrize("bad", [0.0, -3.0])
def test_velocity_must_be_positive(bad):
    with pytest.raises(DetectionError) as excinfo:
        make(velocity=[20.0, 21.0, bad, 29.0])
    assert problems_of(excinfo) == [(3, "velocity")]
    assert "> 0" in str(excinfo.value)


@pytest.mark.parametrize("bad", [None, "fast", True, [1.0]])
def test_non_numbers_are_reported(bad):
    with pytest.raises(DetectionError) as excinfo:
        make(position=[0.0, 100.0, bad, 100.0])
    assert problems_of(excinfo) == [(3, "position")]


def test_huge_magnitudes_are_rejected():
    with pytest.raises(DetectionError) as excinfo:
        make(timestamp=[1.0, 2.0, 3e300, 4.0])
    assert problems_of(excinfo) == [(3, "timestamp")]


def test_all_problems_are_reported_at_once():
    with pytest.raises(DetectionError) as excinfo:
        make(velocity=[-1.0, 21.0, math.nan, 29.0], timestamp=[1.0, "x", 2.0, 3.0])
    assert set(problems_of(excinfo)) == {(1, "velocity"), (3, "velocity"), (2, "timestamp")}


def test_one_sensors_detections_are_valid_but_cannot_be_associated():
    one_sensor = make(position=[5.0, 5.0, 5.0, 5.0])
    assert one_sensor.sensor_id.tolist() == ["S1"] * 4
    with pytest.raises(AssociationError, match="one sensor position"):
        associate(one_sensor, "kmeans")


def test_one_sensor_id_cannot_have_two_positions():
    with pytest.raises(DetectionError) as excinfo:
        make(sensor_id=["A", "B", "A", "A"])
    assert problems_of(excinfo) == [(4, "sensor_id")]
    assert "'A' is at position 0" in str(excinfo.value)


def test_repeated_detection_ids_are_rejected():
    with pytest.raises(DetectionError) as excinfo:
        make(detection_id=["x", "y", "x", "z"])
    assert problems_of(excinfo) == [(3, "detection_id")]


def test_columns_of_different_length_are_rejected():
    with pytest.raises(DetectionError, match="differ in length"):
        make(velocity=[1.0, 2.0])


def test_blank_labels_mean_unlabelled_and_clutter_is_kept():
    d = make(target=["A", "", None, "clutter"])
    assert d.target.tolist() == ["A", None, None, "clutter"]
    assert d.labelled.tolist() == [True, False, False, True]
    assert d.without_labels().labelled.tolist() == [False] * 4


def test_take_and_concatenate_keep_rows_together():
    d = make(detection_id=["a", "b", "c", "e"])
    part = d.take([3, 0])
    assert part.detection_id.tolist() == ["e", "a"]
    np.testing.assert_array_equal(part.velocity, [29.0, 20.0])
    joined = concatenate([part, d.take([1])])
    assert joined.detection_id.tolist() == ["e", "a", "b"]
    with pytest.raises(DetectionError):
        concatenate([])


def test_features_are_optional_per_detection():
    d = make(
        lane=[0, None, "2", ""],
        length=[4.5, "", None, "12.0"],
        vehicle_class=["car", None, " truck ", ""],
    )
    assert d.lane.tolist() == [0, -1, 2, -1]
    assert d.has_lane.tolist() == [True, False, True, False]
    assert d.length[[0, 3]].tolist() == [4.5, 12.0]
    assert d.has_length.tolist() == [True, False, False, True]
    assert d.vehicle_class.tolist() == ["car", None, "truck", None]
    assert d.features == ("lane", "length", "vehicle_class")


def test_without_feature_columns_nothing_is_reported():
    d = make()
    assert d.features == ()
    assert d.lane.tolist() == [-1] * 4 and np.isnan(d.length).all()
    assert d.vehicle_class.tolist() == [None] * 4


def test_features_follow_take_concatenate_and_label_removal():
    d = make(lane=[0, 1, 2, 3], length=[4.0, 5.0, 6.0, 7.0], vehicle_class=["a", "b", "c", "d"])
    taken = d.take([3, 1])
    assert taken.lane.tolist() == [3, 1] and taken.length.tolist() == [7.0, 5.0]
    assert taken.vehicle_class.tolist() == ["d", "b"]
    joined = concatenate([taken, make()])
    assert joined.lane.tolist() == [3, 1, -1, -1, -1, -1]
    assert joined.features == ("lane", "length", "vehicle_class")
    assert d.without_labels().vehicle_class.tolist() == ["a", "b", "c", "d"]
    assert d.without_features().features == ()


def test_only_the_named_features_can_be_kept():
    d = make(lane=[0, 1, 2, 3], length=[4.0, 5.0, 6.0, 7.0], vehicle_class=["a", "b", "c", "d"])
    lanes = d.only_features("lane")
    assert lanes.features == ("lane",) and lanes.lane.tolist() == [0, 1, 2, 3]
    assert np.isnan(lanes.length).all() and lanes.target.tolist() == d.target.tolist()
    assert d.only_features("length", "vehicle_class").features == ("length", "vehicle_class")
    with pytest.raises(ValueError, match="not a detector feature: speed"):
        d.only_features("speed")


def test_classes_coded_by_the_parser_are_the_codes_a_block_would_make():
    """Classes given coded keep their codes in block order (`class_codes`); given as a list, or
    after `take`, they are coded from the values: the same words and codes either way."""
    classes = [None, "truck", "car", "truck", None, "car"]
    words = list(dict.fromkeys(classes))
    coded = CodedTexts(words, np.array([words.index(c) for c in classes]))
    columns = {"position": [0.0, 100.0] * 3, "velocity": [20.0] * 6, "timestamp": range(6)}
    from_codes = Detections.from_columns(**columns, vehicle_class=coded)
    listed = Detections.from_columns(**columns, vehicle_class=classes)
    expected = classes_in_order(classes)
    for d in (from_codes, listed):
        assert d.vehicle_class.tolist() == classes
        assert d.class_codes().words == expected.words == [None, "truck", "car"]
        assert d.class_codes().codes.tolist() == expected.codes.tolist()
    assert from_codes.class_codes() is not listed.class_codes()
    replaced = dataclasses.replace(from_codes, vehicle_class=np.array(classes[::-1], dtype=object))
    assert replaced.class_codes().words == [None, "car", "truck"]  # its own, not the parser's
    picked = from_codes.take([5, 1])
    assert picked.class_codes().words == [None, "car", "truck"]
    assert picked.class_codes().codes.tolist() == [1, 2]
