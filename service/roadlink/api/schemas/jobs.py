"""Jobs: what a job covers and where it stands, and how to ask for one."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Annotated, Any

from pydantic import BaseModel, BeforeValidator, ConfigDict, Field, model_validator

from roadlink.api.schemas.examples import EXAMPLE_ID
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.db.json_columns import Selection
from roadlink.db.models import JobState


def _as_json(selection: Selection) -> dict[str, Any]:
    return selection.to_json()


class JobRead(BaseModel):
    """A job: what it covers and where it stands."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "deployment_id": EXAMPLE_ID,
                    "selection": {"batch_ids": [EXAMPLE_ID]},
                    "associator": DEFAULT_ASSOCIATOR,
                    "params": {},
                    "state": "running",
                    "progress": 0.4,
                    "attempts": 1,
                    "max_attempts": 3,
                    "error": None,
                    "n_detections": None,
                    "created_at": "2026-01-01T12:00:00Z",
                    "started_at": "2026-01-01T12:00:01Z",
                    "finished_at": None,
                    "duration_seconds": None,
                    "request_id": "4bf92f3577b34da6a3ce929d0e0e4736",
                }
            ]
        },
    )

    id: uuid.UUID
    deployment_id: uuid.UUID
    # Shown as stored: the JSON of the typed selection.
    selection: Annotated[dict[str, Any], BeforeValidator(_as_json)] = Field(
        description="{batch_ids: [...]} or {start, end}: the time window [start, end)."
    )
    associator: str
    params: dict[str, Any]
    state: JobState
    progress: float = Field(description="Share of the work done, 0 to 1.")
    attempts: int = Field(description="Runs started so far.")
    max_attempts: int
    error: str | None = Field(description="Why the last run failed, if one did.")
    n_detections: int | None = Field(description="Detections covered (known once it ran).")
    created_at: datetime
    started_at: datetime | None
    finished_at: datetime | None
    duration_seconds: float | None = Field(description="Run time of the successful run.")
    request_id: str | None = Field(
        default=None,
        description="The id of the request that created the job (its X-Request-ID): the "
        "worker's log lines for the job carry it.",
    )


class JobCreate(BaseModel):
    """What to associate: one batch, several, or a deployment's time window [start, end)."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"batch_id": EXAMPLE_ID, "associator": DEFAULT_ASSOCIATOR},
                {"deployment_id": EXAMPLE_ID, "start": 0.0, "end": 60.0, "associator": "kmeans"},
            ]
        },
    )

    batch_id: uuid.UUID | None = Field(default=None, description="One batch.")
    batch_ids: list[uuid.UUID] | None = Field(
        default=None, min_length=1, description="Several batches of one deployment."
    )
    deployment_id: uuid.UUID | None = Field(
        default=None, description="A deployment: its detections with start <= timestamp < end."
    )
    start: float | None = Field(default=None, allow_inf_nan=False, description="Window start.")
    end: float | None = Field(default=None, allow_inf_nan=False, description="Window end.")
    associator: str = Field(
        default=DEFAULT_ASSOCIATOR, description="Name from GET /v1/associators."
    )
    params: dict[str, Any] = Field(default_factory=dict, description="The associator's parameters.")

    @model_validator(mode="after")
    def _one_selection(self) -> JobCreate:
        given = [
            name
            for name in ("batch_id", "batch_ids", "deployment_id")
            if getattr(self, name) is not None
        ]
        if len(given) != 1:
            raise ValueError("give exactly one of batch_id, batch_ids, deployment_id")
        if (self.start is not None or self.end is not None) and self.deployment_id is None:
            raise ValueError("a time window (start, end) needs deployment_id")
        if self.start is not None and self.end is not None and self.start >= self.end:
            raise ValueError("the window [start, end) is empty: start must be before end")
        return self
