"""The result document every associator writes (`AssociationResult.to_dict`, what
`GET /v1/jobs/{id}/result` serves as stored) is exactly what its schema, `AssociationResultRead`
in openapi/openapi.json, documents: no key the schema lacks, none of a wrong type, with detector
features and without."""

from __future__ import annotations

import json
from typing import Any

import pytest

from roadlink.api.schemas import AssociationResultRead
from roadlink.association import associate
from roadlink.association.associators import ASSOCIATORS
from roadlink.simulation import preset, simulate
from tests.helpers import with_features

# Each associator, and parameters that add to the document (min_confidence cuts links).
CASES = [(name, {}) for name in ASSOCIATORS] + [("assignment", {"min_confidence": 0.5})]


@pytest.mark.parametrize(("associator", "params"), CASES)
@pytest.mark.parametrize("labelled", [True, False])
@pytest.mark.parametrize("features", [False, True], ids=["paper", "features"])
def test_the_document_is_what_the_schema_says(
    associator: str, params: dict[str, Any], labelled: bool, features: bool
) -> None:
    if not labelled and ASSOCIATORS[associator].needs_labels:
        pytest.skip("a supervised associator needs labels")
    d = simulate(preset("medium", false_alarm_rate=0.05), seed=2).detections
    if features:  # lanes from some sensors only, lengths and classes from most detections
        d = with_features(d, lane_sensors=4)
    result = associate(d if labelled else d.without_labels(), associator, params)
    document = json.loads(json.dumps(result.to_dict()))  # as stored: through JSON
    read = AssociationResultRead.model_validate(document, strict=True)
    # Whatever the schema does not declare would be dropped here, and the document would differ.
    assert read.model_dump(mode="json", exclude_unset=True) == document
