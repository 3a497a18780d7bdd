"""The result (`association/result.py`): its document and target x sensor CSV, detector features
carried back per detection and summarised per target when the input reports them (without them
the result is exactly what it was before features existed), and `result_from_dict`, which
rebuilds the result `to_dict` wrote, with labels given back by id."""

from __future__ import annotations

import csv
import io
import json
from typing import Any

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.detections import COLUMNS, Detections
from roadlink.association.result import build_result, result_from_dict, road_order
from roadlink.association.result_text import result_json_compact, write_result_json
from roadlink.association.scores import wrongly_grouped
from roadlink.simulation import preset, simulate
from tests.helpers import one_sensor_in_km_per_hour, with_features

FEATURES = ("lane", "length", "vehicle_class")
DETECTION_KEYS = {"detection_id", "sensor_id", "position", "velocity", "timestamp"}


def _without_features(document: dict[str, Any]) -> dict[str, Any]:
    """The document with every feature key removed, target summaries included."""

    def strip(row: dict[str, Any]) -> dict[str, Any]:
        return {k: v for k, v in row.items() if k not in FEATURES}

    targets = [
        {**strip(t), "detections": [strip(r) for r in t["detections"]]} for t in document["targets"]
    ]
    return {**document, "targets": targets, "unassigned": list(map(strip, document["unassigned"]))}


@pytest.mark.parametrize("associator", ["assignment", "kmeans++", "svm-linear"])
def test_without_features_the_document_has_the_keys_it_always_had(associator: str) -> None:
    d = simulate(preset("large", false_alarm_rate=0.05), seed=1).detections
    result = associate(d, associator)
    document = result.to_dict()
    rows = [r for t in document["targets"] for r in t["detections"]] + document["unassigned"]
    assert {k for r in rows for k in r} <= DETECTION_KEYS | {"link_confidence"}
    assert {k for t in document["targets"] for k in t} <= {"target", "confidence", "detections"}
    header = result.to_matrix_csv().splitlines()[0].split(",")
    assert not [h for h in header if h.endswith(FEATURES)]


@pytest.mark.parametrize(
    ("associator", "ignoring_features"),
    [("assignment", {"feature_weight": 0.0}), ("kmeans++", {})],
)
def test_features_add_keys_and_columns_and_change_nothing_else(
    associator: str, ignoring_features: dict[str, float]
) -> None:
    """With the associator told to ignore the features (K-means ignores them by default): the
    same grouping, and the same document and matrix once the feature keys and columns are taken
    out."""
    d = simulate(preset("large", false_alarm_rate=0.05), seed=1).detections
    plain = associate(d, associator, ignoring_features)
    featured = associate(with_features(d, lane_sensors=5), associator, ignoring_features)
    assert np.array_equal(plain.groups, featured.groups)
    assert _without_features(featured.to_dict()) == plain.to_dict()
    matrix = list(csv.DictReader(io.StringIO(featured.to_matrix_csv())))
    kept = [{k: v for k, v in row.items() if not k.endswith(FEATURES)} for row in matrix]
    assert kept == list(csv.DictReader(io.StringIO(plain.to_matrix_csv())))


def test_the_matrix_has_a_column_per_sensor_and_feature_reported() -> None:
    d = with_features(simulate(preset("medium"), seed=3).detections, lane_sensors=2)
    result = associate(d, "kmeans++")
    matrix = list(csv.DictReader(io.StringIO(result.to_matrix_csv())))
    sensors = list(dict.fromkeys(d.sensor_id[np.argsort(d.position)].tolist()))
    for sensor in sensors:
        assert {f"{sensor}_{name}" for name in FEATURES} <= matrix[0].keys()
    by_id = {d.detection_id[i]: i for i in range(len(d))}
    for row in matrix:
        for sensor in sensors:
            if not row[f"{sensor}_detection_id"] or ";" in row[f"{sensor}_detection_id"]:
                continue
            i = by_id[row[f"{sensor}_detection_id"]]
            lane = "" if d.lane[i] < 0 else str(d.lane[i])
            assert row[f"{sensor}_lane"] == lane  # empty beyond the sensors that report lanes
            assert row[f"{sensor}_length"] == repr(float(d.length[i]))
            assert row[f"{sensor}_vehicle_class"] == d.vehicle_class[i]
    assert any(row[f"{sensors[-1]}_lane"] == "" for row in matrix)
    assert any(row[f"{sensors[0]}_lane"] != "" for row in matrix)


def test_a_target_takes_its_median_length_and_most_common_class() -> None:
    d = with_features(simulate(preset("small"), seed=2).detections)
    result = associate(d, "assignment")
    members = result.target_members()[0]
    d.length[members[0]] = 99.0  # one faulty loop
    d.vehicle_class[members[:2]] = "bus"  # two of ten say bus
    summary = result.target_features(members, d.features)
    assert summary["length"] == float(np.median(d.length[members]))
    assert summary["vehicle_class"] != "bus"
    d.length[members] = np.nan
    d.vehicle_class[members] = None
    assert result.target_features(members, d.features) == {"length": None, "vehicle_class": None}


def test_the_document_round_trips_and_the_labels_score_it_again() -> None:
    detections = simulate(preset("large", false_alarm_rate=0.05), seed=3).detections
    result = associate(detections, "kmeans++")
    document = json.loads(json.dumps(result.to_dict()))  # as stored: through JSON
    labels = dict(zip(detections.detection_id.tolist(), detections.target.tolist(), strict=True))

    rebuilt = result_from_dict(document, labels)
    assert rebuilt.to_dict() == document
    assert rebuilt.metrics == result.metrics
    wrong = wrongly_grouped(result.groups, detections.target).sum()
    assert wrong > 0 and wrongly_grouped(rebuilt.groups, rebuilt.detections.target).sum() == wrong

    unlabelled = result_from_dict(document)
    assert unlabelled.metrics is None
    assert all(t is None for t in unlabelled.detections.target)
    assert np.array_equal(np.sort(unlabelled.groups), np.sort(result.groups))


def test_the_parameters_an_associator_ran_with_round_trip() -> None:
    detections = simulate(preset("medium"), seed=1).detections
    document = json.loads(json.dumps(associate(detections, "assignment").to_dict()))
    assert document["effective_params"]["max_skip"] == document["params"]["max_skip"] == 2
    assert result_from_dict(document).to_dict()["effective_params"] == document["effective_params"]


def test_what_the_associator_found_wrong_with_the_detectors_is_in_the_document() -> None:
    """A sensor in km/h among sensors in m/s: one sentence naming it, in both JSON writers'
    documents, round-tripped; no key at all where nothing is wrong."""
    result = associate(one_sensor_in_km_per_hour(5), "assignment")
    (warning,) = result.warnings
    assert warning.startswith("the sensor at position 1450 reads speeds about 3.")
    document = result.to_dict()
    assert document["warnings"] == [warning]
    assert json.loads(result_json_compact(result))["warnings"] == [warning]
    written = io.BytesIO()
    write_result_json(result, written)
    assert json.loads(written.getvalue())["warnings"] == [warning]
    assert result_from_dict(json.loads(json.dumps(document))).warnings == (warning,)
    plain = associate(simulate(preset("medium"), seed=1).detections, "assignment")
    assert plain.warnings == () and "warnings" not in plain.to_dict()


def test_detector_features_round_trip_with_each_target_summarised() -> None:
    detections = with_features(
        simulate(preset("large", false_alarm_rate=0.1), seed=4).detections, lane_sensors=3
    ).without_labels()
    document = json.loads(json.dumps(associate(detections, "assignment").to_dict()))
    rebuilt = result_from_dict(document)
    assert rebuilt.to_dict() == document
    assert rebuilt.detections.features == ("lane", "length", "vehicle_class")
    rows = [r for t in document["targets"] for r in t["detections"]] + document["unassigned"]
    assert all({"lane", "length", "vehicle_class"} <= r.keys() for r in rows)
    assert any(r["lane"] is None for r in rows) and any(r["length"] is None for r in rows)
    for target in document["targets"]:
        lengths = [r["length"] for r in target["detections"] if r["length"] is not None]
        classes = [r["vehicle_class"] for r in target["detections"] if r["vehicle_class"]]
        assert target["length"] == (float(np.median(lengths)) if lengths else None)
        assert target["vehicle_class"] == (max(classes, key=classes.count) if classes else None)


def test_a_feature_no_detection_reports_is_absent_from_the_document() -> None:
    base = simulate(preset("medium"), seed=2).detections
    only_lanes = with_features(base)
    lanes = Detections(*(getattr(base, n) for n in COLUMNS[:6]), lane=only_lanes.lane)
    lanes = lanes.without_labels()
    document = associate(lanes, "kmeans++").to_dict()
    keys = {k for t in document["targets"] for r in t["detections"] for k in r}
    assert "lane" in keys and not keys & {"length", "vehicle_class"}
    assert not {"length", "vehicle_class"} & set(document["targets"][0])
    assert result_from_dict(json.loads(json.dumps(document))).to_dict() == document


def test_target_confidences_are_each_targets_confidence():
    """At once, with the same floats as one product per target (links missing or not)."""
    rng = np.random.default_rng(7)
    d = simulate(preset("small"), seed=7).detections
    n = len(d)
    links = np.where(rng.random(n) < 0.2, np.nan, rng.random(n) ** 3)
    result = build_result(d, rng.integers(-1, 9, n), "x", {}, link_confidence=links)
    members = result.target_members()
    assert result.target_confidences(members) == [result.target_confidence(m) for m in members]
    plain = build_result(d, rng.integers(-1, 9, n), "x", {})
    assert plain.target_confidences(members) == [None] * len(members)


def test_road_order_is_lexsorts_order_with_ties_and_signed_zeros():
    """Targets' members in the order `np.lexsort((timestamp, position, groups))` gives, equal
    rows in their order, -0.0 and 0.0 one position (or one time): on rows with many ties."""
    rng = np.random.default_rng(5)
    for trial in range(200):
        n = int(rng.integers(1, 300))
        groups = rng.integers(0, 8, n)
        position = rng.choice([0.0, -0.0, 100.0, 250.0, 1e-300, -5.0], n)
        times = [0.0, -0.0, 1.0, 2.5]
        timestamp = rng.choice(times, n) if trial % 2 else rng.standard_normal(n)
        expected = np.lexsort((timestamp, position, groups))
        assert np.array_equal(road_order(groups, position, timestamp), expected)


def test_target_members_are_the_lexsorted_assigned_detections():
    d = simulate(preset("small", duplicate_probability=0.2), seed=4).detections
    groups = np.random.default_rng(1).integers(-1, 30, len(d))
    result = build_result(d, groups, "x", {})
    groups = result.groups  # renumbered
    order = np.lexsort((d.timestamp, d.position, groups))
    assigned = order[groups[order] >= 0]
    expected = np.split(assigned, np.flatnonzero(np.diff(groups[assigned])) + 1)
    members = result.target_members()
    assert len(members) == len(expected)
    assert all(np.array_equal(m, e) for m, e in zip(members, expected, strict=True))
