"""The webhook bodies: the event types offered, and a delivery shown with its event parsed
(the stored payload itself is not repeated)."""

from __future__ import annotations

import typing
import uuid

import orjson

from roadlink.api.schemas.webhooks import DeliveryRead, EventType, WebhookCreated
from roadlink.db.models import WebhookDelivery, utcnow
from roadlink.queue.webhooks import EVENT_TYPES


def test_the_api_offers_every_event_type_the_outbox_knows() -> None:
    assert typing.get_args(EventType) == EVENT_TYPES


def test_a_delivery_shows_its_event_as_sent_and_not_the_raw_payload() -> None:
    event = {"id": str(uuid.uuid4()), "type": "job.finished", "data": {"job": {"id": "j"}}}
    delivery = WebhookDelivery(
        id=uuid.uuid4(),
        webhook_id=uuid.uuid4(),
        event_id=uuid.UUID(event["id"]),  # type: ignore[arg-type]
        event_type="job.finished",
        payload=orjson.dumps(event).decode(),
        state="pending",
        attempts=0,
        created_at=utcnow(),
    )
    shown = DeliveryRead.model_validate(delivery).model_dump(mode="json")
    assert shown["event"] == event and "payload" not in shown
    assert shown["state"] == "pending" and shown["last_status_code"] is None


def test_the_created_example_is_a_valid_body() -> None:
    [example] = WebhookCreated.model_config["json_schema_extra"]["examples"]  # type: ignore[index]
    assert WebhookCreated.model_validate(example).secret.startswith("whsec_")
