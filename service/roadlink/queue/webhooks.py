"""The webhook outbox: events written as delivery rows in the transaction that makes them
happen, then claimed, attempted and rescheduled by the workers (`queue/webhook_dispatch.py`).

An event is recorded only when its transaction commits (it is a row of that transaction), and
sent at least once: a worker claims a due delivery by pushing its next attempt past the time a
send may take, so a worker that dies mid-send leaves it due again for another. Every outcome is
guarded by the attempt it answers, so a sender that lost its claim cannot overwrite a newer one.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import orjson
from sqlalchemy import Select, bindparam, select, update
from sqlalchemy.orm import Session

from roadlink.db.drivers import Driver, driver_of, prebuilt
from roadlink.db.live_records import vehicle_document
from roadlink.db.models import Job, JobResult, LiveVehicle, Webhook, WebhookDelivery, utcnow

JOB_FINISHED = "job.finished"
"""A job succeeded, failed or was cancelled."""

VEHICLE_PUBLISHED = "vehicle.published"
"""A live association published a vehicle (final: it will not change)."""

EVENT_TYPES = (JOB_FINISHED, VEHICLE_PUBLISHED)
"""Every event type a webhook may subscribe to. Types are `<resource>.<what happened>`, so that
new ones are added here without changing old ones."""

PENDING, DELIVERED, FAILED = "pending", "delivered", "failed"
"""A delivery's states: due for an attempt (now or after a backoff), answered with a 2xx, or out
of attempts."""


def _clock(session: Session, now: datetime | None) -> Any:
    return driver_of(session).clock() if now is None else now


def record_job_finished(session: Session, job_ids: Iterable[uuid.UUID]) -> int:
    """Add a `job.finished` delivery for each webhook of each job's deployment that subscribes,
    in the caller's transaction (the one that finishes the jobs). Returns how many."""
    ids = list(job_ids)
    if not ids:
        return 0
    # Whether any webhook subscribes first, by one read of a statement built once: most
    # deployments have none, and then the jobs need not be read back (a paper-size job's finish
    # paid a flush and a load of its row for nothing).
    hooks, _ = prebuilt(session, "job-webhooks", _build_job_webhooks)
    found = session.connection().execute(hooks, {"job_ids": ids}).scalars()
    if not any(JOB_FINISHED in (types or ()) for types in found):
        return 0
    deployments = select(Job.deployment_id).where(Job.id.in_(ids))
    subscribed = _subscribers(session, deployments, JOB_FINISHED)
    if not subscribed:
        return 0
    session.flush()  # the jobs' new state and a succeeded job's result are read back below
    jobs = session.execute(
        select(Job, JobResult.accuracy)
        .outerjoin(JobResult, JobResult.job_id == Job.id)
        .where(Job.id.in_(ids))
        .execution_options(populate_existing=True)
    ).all()
    now = _clock(session, None)
    count = 0
    for job, accuracy in jobs:
        data = {"job": _job_data(job, accuracy)}
        count += _add(session, subscribed, _event(JOB_FINISHED, job.deployment_id, data), now)
    session.flush()
    return count


def _build_job_webhooks(driver: Driver, now: Any, bound: bool) -> Any:
    """The event types of every webhook of the deployments of the jobs `job_ids`."""
    jobs = select(Job.deployment_id).where(Job.id.in_(bindparam("job_ids", expanding=True)))
    return select(Webhook.event_types).where(Webhook.deployment_id.in_(jobs))


def record_vehicles_published(session: Session, vehicles: list[LiveVehicle]) -> int:
    """Add a `vehicle.published` delivery per vehicle for each webhook of its deployment that
    subscribes, in the caller's transaction (the live step's, which publishes them, after they
    have their cursor). Returns how many."""
    deployments = {v.deployment_id for v in vehicles}
    subscribed = _subscribers(session, deployments, VEHICLE_PUBLISHED) if deployments else []
    if not subscribed:
        return 0
    now = _clock(session, None)
    count = 0
    for vehicle in vehicles:
        event = _event(VEHICLE_PUBLISHED, vehicle.deployment_id, {"vehicle": _vehicle(vehicle)})
        count += _add(session, subscribed, event, now)
    session.flush()
    return count


def _subscribers(
    session: Session, deployments: set[uuid.UUID] | Select[Any], event_type: str
) -> list[Webhook]:
    """The webhooks of these deployments (ids, or a select of them) that receive
    `event_type`."""
    hooks = session.scalars(select(Webhook).where(Webhook.deployment_id.in_(deployments))).all()
    return [h for h in hooks if event_type in h.event_types]


def _add(session: Session, subscribed: list[Webhook], event: Event, now: Any) -> int:
    """One delivery of `event` to each subscribed webhook of its deployment; how many."""
    mine = [h for h in subscribed if h.deployment_id == event.deployment_id]
    session.add_all(_delivery(h.id, event, now) for h in mine)
    return len(mine)


def _vehicle(vehicle: LiveVehicle) -> dict[str, Any]:
    """The vehicle as the deployment's feed shows it (GET .../vehicles), and where that is."""
    feed = f"/v1/deployments/{vehicle.deployment_id}/vehicles"
    return {
        **vehicle_document(vehicle),
        "links": {"feed": f"{feed}?after={vehicle.seq - 1}", "stream": f"{feed}/stream"},
    }


def _job_data(job: Job, accuracy: float | None) -> dict[str, Any]:
    return {
        "id": str(job.id),
        "state": job.state.value,
        "associator": job.associator,
        "error": job.error,
        "n_detections": job.n_detections,
        "accuracy": accuracy,
        "finished_at": None if job.finished_at is None else _iso(job.finished_at),
        "links": {"job": f"/v1/jobs/{job.id}", "result": f"/v1/jobs/{job.id}/result"},
    }


def _iso(moment: datetime) -> str:
    return moment.isoformat().replace("+00:00", "Z")


@dataclass(frozen=True)
class Event:
    id: uuid.UUID
    type: str
    body: str
    deployment_id: uuid.UUID | None = None  # whose webhooks receive it (not needed to resend)


def _event(event_type: str, deployment_id: uuid.UUID, data: dict[str, Any]) -> Event:
    """An event as its receivers get it: the same envelope for every type."""
    event_id = uuid.uuid4()
    envelope = {
        "id": str(event_id),
        "type": event_type,
        "created_at": _iso(utcnow()),
        "deployment_id": str(deployment_id),
        "data": data,
    }
    return Event(event_id, event_type, orjson.dumps(envelope).decode(), deployment_id)


def _delivery(webhook_id: uuid.UUID, event: Event, now: Any) -> WebhookDelivery:
    return WebhookDelivery(
        id=uuid.uuid4(),
        webhook_id=webhook_id,
        event_id=event.id,
        event_type=event.type,
        payload=event.body,
        state=PENDING,
        attempts=0,
        next_attempt_at=now,
        created_at=utcnow(),
    )


@dataclass(frozen=True)
class DueDelivery:
    """What a worker needs to send one attempt of a delivery."""

    id: uuid.UUID
    event_id: uuid.UUID
    event_type: str
    payload: str
    attempt: int
    url: str
    secret: str
    # What the event is about, for the log line of each attempt (logs.CONTEXT_FIELDS): the
    # deployment, and for a job's event the job and the request that created it.
    context: dict[str, str]


def has_due_delivery(session: Session, *, now: datetime | None = None) -> bool:
    """Whether a delivery is due: a read, so idle workers polling SQLite take no write lock."""
    now = _clock(session, now)
    query = select(WebhookDelivery.id).where(
        WebhookDelivery.state == PENDING, WebhookDelivery.next_attempt_at <= now
    )
    return session.execute(query.limit(1)).first() is not None


def claim_due_delivery(
    session: Session, *, claim_seconds: float, now: datetime | None = None
) -> DueDelivery | None:
    """Take the delivery due longest ago for one attempt, or None when none is due: its attempt
    is counted and its next one pushed `claim_seconds` away (past the send's timeout), so no
    other worker takes it meanwhile and, should this one die, it comes due again."""
    now = _clock(session, now)
    candidate = driver_of(session).lock_for_claim(
        select(WebhookDelivery.id)
        .where(WebhookDelivery.state == PENDING, WebhookDelivery.next_attempt_at <= now)
        .order_by(WebhookDelivery.next_attempt_at)
        .limit(1)
    )
    row = session.execute(
        update(WebhookDelivery)
        .where(WebhookDelivery.id == candidate.scalar_subquery())
        .where(WebhookDelivery.state == PENDING)
        .values(
            attempts=WebhookDelivery.attempts + 1,
            last_attempt_at=now,
            next_attempt_at=now + timedelta(seconds=claim_seconds),
        )
        .returning(
            WebhookDelivery.id,
            WebhookDelivery.event_id,
            WebhookDelivery.event_type,
            WebhookDelivery.payload,
            WebhookDelivery.attempts,
            WebhookDelivery.webhook_id,
        )
        .execution_options(synchronize_session=False)
    ).first()
    if row is None:
        return None
    hook = session.get(Webhook, row.webhook_id)
    if hook is None:  # deleted meanwhile: its deliveries go with it
        return None
    return DueDelivery(
        row.id,
        row.event_id,
        row.event_type,
        row.payload,
        row.attempts,
        hook.url,
        hook.secret,
        _log_context(session, hook.deployment_id, row.payload),
    )


def _log_context(session: Session, deployment_id: uuid.UUID, payload: str) -> dict[str, str]:
    context = {"deployment_id": str(deployment_id)}
    job = orjson.loads(payload).get("data", {}).get("job")
    if isinstance(job, dict) and isinstance(job.get("id"), str):
        context["job_id"] = job["id"]
        # The request that created the job, if the job is still stored (retention may not).
        request_id = session.scalar(select(Job.request_id).where(Job.id == uuid.UUID(job["id"])))
        if request_id is not None:
            context["request_id"] = request_id
    return context


@dataclass(frozen=True)
class Backoff:
    """When a failed attempt is tried again: `first` seconds after the first, doubling, at most
    `longest`; after `max_attempts` attempts, never."""

    max_attempts: int
    first: float
    longest: float

    def delay(self, attempt: int) -> float:
        return float(min(self.longest, self.first * 2 ** (attempt - 1)))


def record_attempt(
    session: Session,
    *,
    delivery: DueDelivery,
    status_code: int | None,
    error: str | None,
    backoff: Backoff,
    now: datetime | None = None,
) -> str | None:
    """Record how an attempt went (a 2xx status is delivered); returns the delivery's new state,
    or None when the attempt was no longer the delivery's latest (another took it over)."""
    now = _clock(session, now)
    values: dict[str, Any] = {"last_status_code": status_code, "last_error": error}
    if status_code is not None and 200 <= status_code < 300 and error is None:
        state = DELIVERED
        values |= {"delivered_at": now, "next_attempt_at": None}
    elif delivery.attempt >= backoff.max_attempts:
        state = FAILED
        values |= {"next_attempt_at": None}
    else:
        state = PENDING
        values["next_attempt_at"] = now + timedelta(seconds=backoff.delay(delivery.attempt))
    updated = session.execute(
        update(WebhookDelivery)
        .where(WebhookDelivery.id == delivery.id, WebhookDelivery.attempts == delivery.attempt)
        .values(state=state, **values)
        .execution_options(synchronize_session=False)
    ).rowcount  # type: ignore[attr-defined]
    return state if updated == 1 else None


def redeliver(session: Session, *, delivery: WebhookDelivery) -> WebhookDelivery:
    """A new delivery of the same event (same id and body) to the same webhook, due now; the
    original keeps its log."""
    again = _delivery(
        delivery.webhook_id,
        Event(delivery.event_id, delivery.event_type, delivery.payload),
        _clock(session, None),
    )
    again.redelivery_of = delivery.id
    session.add(again)
    session.flush()
    return again
