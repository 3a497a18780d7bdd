"""Webhooks: a deployment's endpoints for its events, and their delivery log."""

from __future__ import annotations

import uuid
from datetime import datetime
from typing import Any, Literal

import orjson
from pydantic import BaseModel, ConfigDict, Field, computed_field

from roadlink.api.schemas.examples import EXAMPLE_ID

# Every event type (roadlink.queue.webhooks.EVENT_TYPES; a test keeps the two the same).
EventType = Literal["job.finished", "vehicle.published"]


def _default_event_types() -> list[EventType]:
    # Not vehicle.published: one event per vehicle of a live association is many requests, for
    # whoever asks for them.
    return ["job.finished"]


class WebhookCreate(BaseModel):
    """An endpoint to receive the deployment's events."""

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [{"url": "https://hooks.example/roadlink", "event_types": ["job.finished"]}]
        },
    )

    url: str = Field(
        min_length=1,
        max_length=2000,
        description="Where the events are POSTed: https:// (http:// only to a loopback address, "
        "unless ROADLINK_WEBHOOK_ALLOW_HTTP).",
    )
    event_types: list[EventType] = Field(
        default_factory=_default_event_types,
        min_length=1,
        description="The events it receives (default: job.finished; vehicle.published, one "
        "event per vehicle a live association publishes, only when asked for).",
    )
    description: str | None = Field(default=None, max_length=200, description="For people.")


class WebhookRead(BaseModel):
    """A webhook (its secret is shown once, when it is created)."""

    model_config = ConfigDict(from_attributes=True)

    id: uuid.UUID
    deployment_id: uuid.UUID
    url: str
    event_types: list[str]
    description: str | None
    created_at: datetime


class WebhookCreated(WebhookRead):
    """A new webhook with its signing secret, shown this once: keep it to verify the
    `Roadlink-Signature` header of each delivery."""

    model_config = ConfigDict(
        from_attributes=True,
        json_schema_extra={
            "examples": [
                {
                    "id": EXAMPLE_ID,
                    "deployment_id": EXAMPLE_ID,
                    "url": "https://hooks.example/roadlink",
                    "event_types": ["job.finished"],
                    "description": None,
                    "created_at": "2026-01-01T12:00:00Z",
                    "secret": "whsec_3q2x...",
                }
            ]
        },
    )

    secret: str


class DeliveryRead(BaseModel):
    """One event sent (or to be sent) to a webhook, and how its attempts went."""

    model_config = ConfigDict(from_attributes=True)

    id: uuid.UUID
    webhook_id: uuid.UUID
    event_id: uuid.UUID = Field(description="The same in every delivery of the event.")
    event_type: str
    state: Literal["pending", "delivered", "failed"] = Field(
        description="pending: an attempt is due (now or after a backoff); delivered: answered "
        "with a 2xx; failed: out of attempts (redeliver to try again)."
    )
    attempts: int
    next_attempt_at: datetime | None
    last_attempt_at: datetime | None
    last_status_code: int | None = Field(description="The receiver's last HTTP status, if any.")
    last_error: str | None = Field(description="Why the last attempt failed, if it did.")
    delivered_at: datetime | None
    redelivery_of: uuid.UUID | None = Field(description="The delivery this one sends again.")
    created_at: datetime
    payload: str = Field(exclude=True)

    @computed_field(description="The event, as the request body sent.")  # type: ignore[prop-decorator]
    @property
    def event(self) -> dict[str, Any]:
        event: dict[str, Any] = orjson.loads(self.payload)
        return event
