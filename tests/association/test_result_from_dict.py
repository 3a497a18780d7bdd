"""`result_from_dict` rebuilds the result `to_dict` wrote, with labels given back by id."""

from __future__ import annotations

import json

import numpy as np

from roadlink.association import associate
from roadlink.association.result import result_from_dict
from roadlink.association.scores import wrongly_grouped
from roadlink.simulation import preset, simulate


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
