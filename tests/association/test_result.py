"""`result_from_dict` rebuilds the result `to_dict` wrote, with labels given back by id."""

from __future__ import annotations

import json

import numpy as np

from roadlink.association import associate
from roadlink.association.detections import COLUMNS, Detections
from roadlink.association.result import result_from_dict
from roadlink.association.scores import wrongly_grouped
from roadlink.simulation import preset, simulate
from tests.helpers import with_features


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
