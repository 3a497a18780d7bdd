"""Webhooks: where a deployment's events are POSTed, signed, and their delivery log."""

from __future__ import annotations

import uuid

from fastapi import APIRouter, Query, Response

from roadlink.api.deps import SessionDep, SettingsDep
from roadlink.api.errors import problem_responses
from roadlink.api.schemas import DeliveryRead, WebhookCreate, WebhookCreated, WebhookRead
from roadlink.services import webhooks

router = APIRouter(prefix="/v1/deployments/{deployment_id}/webhooks", tags=["webhooks"])

LIMIT = Query(default=100, ge=1, le=1000, description="Page size.")
OFFSET = Query(default=0, ge=0, le=2**31 - 1, description="Items to skip.")


@router.post(
    "",
    name="create",
    status_code=201,
    response_model=WebhookCreated,
    responses=problem_responses(404, 413, 422),
    summary="Register a webhook",
)
def create_webhook(
    deployment_id: uuid.UUID, body: WebhookCreate, session: SessionDep, settings: SettingsDep
) -> WebhookCreated:
    """Events of the deployment will be POSTed to `url`, signed with the secret returned here,
    once (see docs/service.md, Webhooks, to verify a delivery)."""
    webhook = webhooks.create_webhook(
        session,
        deployment_id=deployment_id,
        url=body.url,
        event_types=body.event_types,
        description=body.description,
        allow_http=settings.webhook_allow_http,
    )
    session.commit()
    return WebhookCreated.model_validate(webhook)


@router.get(
    "",
    name="list",
    response_model=list[WebhookRead],
    responses=problem_responses(404, 422),
    summary="List a deployment's webhooks",
)
def list_webhooks(
    deployment_id: uuid.UUID, session: SessionDep, limit: int = LIMIT, offset: int = OFFSET
) -> list[WebhookRead]:
    """The deployment's webhooks, oldest first (without their secrets)."""
    found = webhooks.list_webhooks(session, deployment_id=deployment_id, limit=limit, offset=offset)
    return [WebhookRead.model_validate(w) for w in found]


@router.get(
    "/{webhook_id}",
    name="get",
    response_model=WebhookRead,
    responses=problem_responses(404, 422),
    summary="Get a webhook",
)
def get_webhook(
    deployment_id: uuid.UUID, webhook_id: uuid.UUID, session: SessionDep
) -> WebhookRead:
    """One webhook (without its secret)."""
    webhook = webhooks.require_webhook(session, deployment_id, webhook_id)
    return WebhookRead.model_validate(webhook)


@router.delete(
    "/{webhook_id}",
    name="delete",
    status_code=204,
    responses=problem_responses(404, 422),
    summary="Delete a webhook",
)
def delete_webhook(
    deployment_id: uuid.UUID, webhook_id: uuid.UUID, session: SessionDep
) -> Response:
    """Delete the webhook and its delivery log; deliveries not yet sent are dropped."""
    webhooks.delete_webhook(session, deployment_id=deployment_id, webhook_id=webhook_id)
    session.commit()
    return Response(status_code=204)


@router.get(
    "/{webhook_id}/deliveries",
    name="list_deliveries",
    response_model=list[DeliveryRead],
    responses=problem_responses(404, 422),
    summary="A webhook's delivery log",
)
def list_deliveries(
    deployment_id: uuid.UUID,
    webhook_id: uuid.UUID,
    session: SessionDep,
    limit: int = LIMIT,
    offset: int = OFFSET,
) -> list[DeliveryRead]:
    """Every delivery of the webhook, newest first: its event, state, attempts and the
    receiver's last answer."""
    found = webhooks.list_deliveries(
        session, deployment_id=deployment_id, webhook_id=webhook_id, limit=limit, offset=offset
    )
    return [DeliveryRead.model_validate(d) for d in found]


@router.post(
    "/{webhook_id}/deliveries/{delivery_id}/redeliver",
    name="redeliver",
    status_code=202,
    response_model=DeliveryRead,
    responses=problem_responses(404, 422),
    summary="Send a delivery's event again",
)
def redeliver(
    deployment_id: uuid.UUID, webhook_id: uuid.UUID, delivery_id: uuid.UUID, session: SessionDep
) -> DeliveryRead:
    """Queue the event again, as a new delivery (same event id and body) that the workers send
    now, with the usual retries; the original keeps its log."""
    again = webhooks.redeliver_delivery(
        session, deployment_id=deployment_id, webhook_id=webhook_id, delivery_id=delivery_id
    )
    session.commit()
    return DeliveryRead.model_validate(again)
