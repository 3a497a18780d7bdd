"""Job bodies (`api/schemas/jobs.py`): a request selects exactly one of a batch, batches or a
deployment's time window, and a job is shown with its typed selection as stored JSON."""

from __future__ import annotations

import uuid
from typing import Any

import pytest
from pydantic import ValidationError

from roadlink.api.schemas import JobCreate, JobRead
from roadlink.db.json_columns import BatchSelection, WindowSelection
from roadlink.db.models import JobState
from tests.helpers import unsaved_job

ID = str(uuid.uuid4())


@pytest.mark.parametrize("body", JobCreate.model_config["json_schema_extra"]["examples"])  # type: ignore[index]
def test_the_documented_examples_are_valid_requests(body: dict[str, Any]) -> None:
    JobCreate.model_validate(body)


@pytest.mark.parametrize(
    "body",
    [
        {"batch_id": ID},
        {"batch_ids": [ID, ID]},
        {"deployment_id": ID},
        {"deployment_id": ID, "start": 0.0},
        {"deployment_id": ID, "start": 0.0, "end": 60.0, "associator": "kmeans", "params": {}},
    ],
)
def test_one_selection_is_a_job(body: dict[str, Any]) -> None:
    assert JobCreate.model_validate(body).associator == body.get("associator", "assignment")


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ({}, "give exactly one of batch_id, batch_ids, deployment_id"),
        ({"batch_id": ID, "deployment_id": ID}, "give exactly one"),
        ({"batch_ids": []}, "at least 1 item"),
        ({"batch_id": ID, "start": 0.0}, "a time window (start, end) needs deployment_id"),
        ({"deployment_id": ID, "start": 5.0, "end": 5.0}, "start must be before end"),
        ({"deployment_id": ID, "end": float("inf")}, "finite number"),
        ({"batch_id": ID, "priority": 1}, "Extra inputs are not permitted"),
    ],
)
def test_anything_else_is_refused_saying_why(body: dict[str, Any], message: str) -> None:
    with pytest.raises(ValidationError, match=message.replace("(", r"\(").replace(")", r"\)")):
        JobCreate.model_validate(body)


def test_a_job_shows_its_selection_as_stored_json() -> None:
    batch = uuid.uuid4()
    shown = JobRead.model_validate(unsaved_job(selection=BatchSelection((batch,))))
    assert shown.selection == {"batch_ids": [str(batch)]}
    assert shown.state == JobState.QUEUED and shown.started_at is None
    window = JobRead.model_validate(unsaved_job(selection=WindowSelection(0.0, None)))
    assert window.model_dump(mode="json")["selection"] == {"start": 0.0, "end": None}
