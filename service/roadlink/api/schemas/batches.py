"""Batches: detections posted by a gateway, and the association asked for with them."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from roadlink.api.schemas.examples import EXAMPLE_ID
from roadlink.api.schemas.jobs import JobRead
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.feature_columns import MAX_CLASS_CHARS, MAX_LANE, MAX_LENGTH
from roadlink.db.models import Batch, Job


class DetectionIn(BaseModel):
    """One sensor report (the same fields as the detection CSV's columns). The detector features
    `lane`, `length` and `vehicle_class` are optional per detection; the result carries them back
    when any detection of the job reports them."""

    position: float = Field(description="Sensor position along the road (metres).")
    velocity: float = Field(gt=0, description="Measured velocity (metres per second, > 0).")
    timestamp: float = Field(description="Time of the detection (seconds).")
    sensor_id: str | None = Field(
        default=None, description="Sensor id (named by position if absent)."
    )
    detection_id: str | None = Field(
        default=None, description="Unique id within the batch (d1, d2, ... if absent)."
    )
    target: str | None = Field(
        default=None,
        description="True target label, for scoring and supervised associators; 'clutter' marks "
        "a false alarm; absent = unlabelled.",
    )
    lane: int | None = Field(
        default=None,
        ge=0,
        le=MAX_LANE,
        description="Detector feature: the lane, a whole number from 0 (the rightmost); absent "
        "or null = not reported.",
    )
    length: float | None = Field(
        default=None,
        gt=0,
        le=MAX_LENGTH,
        description="Detector feature: the vehicle's measured length, > 0 and at most 100, in "
        "the deployment's position unit (metres by default); absent or null = not measured.",
    )
    vehicle_class: str | None = Field(
        default=None,
        max_length=MAX_CLASS_CHARS,
        description="Detector feature: the vehicle class in the deployment's own vocabulary "
        "(car, truck, 5, ...), at most 32 printable characters; absent or null = not reported.",
    )


class AssociateRequest(BaseModel):
    """Which associator to run, with which parameters."""

    model_config = ConfigDict(extra="forbid")

    associator: str = Field(
        default=DEFAULT_ASSOCIATOR, description="Name from GET /v1/associators."
    )
    params: dict[str, Any] = Field(
        default_factory=dict, description="The associator's parameters (its JSON Schema)."
    )


class BatchCreate(BaseModel):
    """A batch of detections, optionally with a job to associate them at once."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {
                    "detections": [
                        {"position": 0.0, "velocity": 41.2, "timestamp": 3.1, "target": "A1"},
                        {"position": 100.0, "velocity": 40.7, "timestamp": 5.5, "target": "A1"},
                    ],
                    "associate": {"associator": DEFAULT_ASSOCIATOR, "params": {}},
                },
                {
                    "detections": [
                        {
                            "position": 0.0,
                            "velocity": 41.2,
                            "timestamp": 3.1,
                            "sensor_id": "S1",
                            "lane": 0,
                            "length": 4.4,
                            "vehicle_class": "car",
                        },
                        {
                            "position": 100.0,
                            "velocity": 40.7,
                            "timestamp": 5.5,
                            "sensor_id": "S2",
                            "lane": None,
                            "length": 4.6,
                            "vehicle_class": "car",
                        },
                    ],
                },
            ]
        },
    )

    detections: list[DetectionIn] = Field(description="The detections, in any order.")
    associate: AssociateRequest | None = Field(
        default=None, description="Enqueue a job for this batch in the same transaction."
    )


class BatchRead(BaseModel):
    """A stored batch, and the job enqueued with it when association was asked for."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "deployment_id": EXAMPLE_ID,
                    "n_detections": 100,
                    "n_labelled": 100,
                    "first_timestamp": 1.2,
                    "last_timestamp": 58.3,
                    "source": "json",
                    "created_at": "2026-01-01T12:00:00Z",
                    "job": None,
                }
            ]
        },
    )

    id: uuid.UUID
    deployment_id: uuid.UUID
    n_detections: int
    n_labelled: int = Field(description="Detections with a true label (scored when associated).")
    first_timestamp: float
    last_timestamp: float
    source: Literal["json", "csv", "simulation"]
    created_at: datetime
    job: JobRead | None = Field(default=None, description="The job enqueued with the batch.")


def batch_read(batch: Batch, job: Job | None) -> BatchRead:
    """The stored batch as the API shows it, with the job enqueued with it."""
    read = BatchRead.model_validate(batch)
    read.job = None if job is None else JobRead.model_validate(job)
    return read
