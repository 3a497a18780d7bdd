"""Storing a batch of detections, with its job when association is asked for, once per
Idempotency-Key; and finding a batch's job."""

from __future__ import annotations

import uuid
import weakref
from collections.abc import Callable
from dataclasses import dataclass
from typing import TypeVar

from sqlalchemy.orm import Session

from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.idempotency_records import find_batch_idempotency_key
from roadlink.db.json_columns import BatchSelection
from roadlink.db.live_records import note_batch
from roadlink.db.models import Batch, Deployment, Job
from roadlink.queue.transitions import enqueue_job
from roadlink.services.deployments import require_deployment
from roadlink.services.idempotency import IdempotentRequest, Recorded, create_once
from roadlink.services.jobs import AssociationAsked, checked_params
from roadlink.settings import Settings

Answer = TypeVar("Answer")


@dataclass(frozen=True)
class ParsedBatch:
    """A request's detections, validated, where they came from, and the association asked for."""

    detections: Detections
    source: str  # json | csv | simulation
    associate: AssociationAsked | None


def store_batch_once(
    session: Session,
    *,
    settings: Settings,
    deployment_id: uuid.UUID,
    parse: Callable[[Deployment], ParsedBatch],
    answer: Callable[[Batch], Answer],
    idempotent: IdempotentRequest | None,
) -> tuple[Answer, bool]:
    """Parse and store a batch of the deployment and commit; with a key its sender used on this
    deployment before, store nothing. Returns the batch's `answer` (taken inside the
    transaction) and whether it replays an earlier request's."""
    deployment = require_deployment(session, deployment_id)

    def find(request: IdempotentRequest) -> Recorded[Answer] | None:
        batch = find_batch_idempotency_key(
            session,
            deployment_id=deployment_id,
            principal=request.principal,
            idempotency_key=request.key,
        )
        if batch is None:
            return None
        return Recorded(batch.request_sha256 or "", f"batch {batch.id}", lambda: answer(batch))

    def create() -> Answer:
        batch = store_batch(
            session,
            settings=settings,
            deployment_id=deployment_id,
            batch=parse(deployment),
            idempotent=idempotent,
        )
        return answer(batch)

    return create_once(session, idempotent, find=find, create=create, new_thing="new detections")


def store_batch(
    session: Session,
    *,
    settings: Settings,
    deployment_id: uuid.UUID,
    batch: ParsedBatch,
    idempotent: IdempotentRequest | None = None,
) -> Batch:
    """Insert the batch and, when asked, its job, in the caller's transaction."""
    batch_id = uuid.uuid4()
    job_id = None
    if batch.associate is not None:
        params = checked_params(batch.associate)
        job = enqueue_job(
            session,
            deployment_id=deployment_id,
            selection=BatchSelection((batch_id,)),
            associator=batch.associate.associator,
            params=params,
            max_attempts=settings.max_attempts,
        )
        job_id = job.id
    stored = repository.insert_batch(
        session,
        batch_id=batch_id,
        deployment_id=deployment_id,
        detections=batch.detections,
        source=batch.source,
        idempotency_key=None if idempotent is None else idempotent.key,
        idempotency_principal=None if idempotent is None else idempotent.principal,
        request_sha256=None if idempotent is None else idempotent.digest,
        job_id=job_id,
    )
    # The deployment's live association, if one runs, takes the batch at its next step.
    note_batch(
        session,
        deployment_id=deployment_id,
        timestamps=batch.detections.timestamp,
        last_position=float(batch.detections.position.max()),
    )
    if batch.associate is not None:
        _enqueued[stored] = job
    return stored


# The job `store_batch` enqueued, while its batch is held: the session keeps only a weak
# reference to a flushed row, so the answer to the POST read the new job back otherwise.
_enqueued: weakref.WeakKeyDictionary[Batch, Job] = weakref.WeakKeyDictionary()


def batch_job(session: Session, batch: Batch) -> Job | None:
    """The job enqueued with the batch, if any."""
    if batch.job_id is None:
        return None
    enqueued = _enqueued.get(batch)
    if enqueued is not None and enqueued.id == batch.job_id:
        return enqueued
    return repository.get_job(session, job_id=batch.job_id)
