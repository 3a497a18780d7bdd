"""Batch bodies (`api/schemas/batches.py`): the documented JSON batch (which the API reads
itself, `api/ingest.py`, so this model is its contract and examples), the association asked for
with it, and a stored batch shown with its job."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

import pytest
from pydantic import ValidationError

from roadlink.api.ingest import parse_json_batch
from roadlink.api.schemas import AssociateRequest, BatchCreate, batch_read
from roadlink.db.json_columns import BatchSelection
from roadlink.db.models import Batch
from tests.helpers import unsaved_job

EXAMPLES = BatchCreate.model_config["json_schema_extra"]["examples"]  # type: ignore[index]


@pytest.mark.parametrize("body", EXAMPLES)
def test_the_documented_examples_are_valid_and_the_api_reads_them(body: dict[str, Any]) -> None:
    documented = BatchCreate.model_validate(body)
    detections, associate = parse_json_batch(
        BatchCreate.model_validate(body).model_dump_json().encode(), None, 10
    )
    assert len(detections) == len(documented.detections) == 2
    assert (associate is None) == (documented.associate is None)


def test_the_association_asked_for_defaults_to_the_default_associator() -> None:
    asked = AssociateRequest()
    assert asked.associator == "assignment" and asked.params == {}
    with pytest.raises(ValidationError, match="Extra inputs are not permitted"):
        AssociateRequest.model_validate({"associator": "kmeans", "seed": 1})


def _batch() -> Batch:
    return Batch(
        id=uuid.uuid4(),
        deployment_id=uuid.uuid4(),
        n_detections=100,
        n_labelled=0,
        first_timestamp=1.0,
        last_timestamp=60.0,
        source="csv",
        created_at=datetime(2026, 1, 1, tzinfo=UTC),
    )


def test_a_stored_batch_is_shown_with_the_job_enqueued_with_it() -> None:
    batch = _batch()
    alone = batch_read(batch, None)
    assert alone.id == batch.id and alone.source == "csv" and alone.job is None
    job = unsaved_job(deployment_id=batch.deployment_id, selection=BatchSelection((batch.id,)))
    shown = batch_read(batch, job)
    assert shown.job is not None and shown.job.id == job.id
    assert shown.job.selection == {"batch_ids": [str(batch.id)]}
