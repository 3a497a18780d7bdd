"""What more than one router does: find a deployment, check an association request before it is
queued, store a batch (with its job) and read it back. Routers import these; no router imports
another router (tests/test_architecture.py)."""

from __future__ import annotations

import uuid
from typing import Any

from sqlalchemy.orm import Session

from roadlink.api.errors import ApiProblem, ProblemItem
from roadlink.api.schemas import AssociateRequest, BatchRead, JobRead
from roadlink.association import parse_params
from roadlink.association.associators import AssociationError
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.models import Batch, Deployment
from roadlink.queue.jobs import enqueue_job
from roadlink.settings import Settings


def require_deployment(session: Session, deployment_id: uuid.UUID) -> Deployment:
    """The deployment, or 404 naming it."""
    deployment = repository.get_deployment(session, deployment_id=deployment_id)
    if deployment is None:
        raise ApiProblem(404, f"there is no deployment {deployment_id}")
    return deployment


def replay(session: Session, batch: Batch, digest: str) -> BatchRead:
    """The original answer to a repeated request, or 422 if the key came with another body."""
    if batch.request_sha256 != digest:
        raise ApiProblem(
            422,
            f"Idempotency-Key '{batch.idempotency_key}' was used for a different request "
            f"(batch {batch.id}); use a new key for new detections",
            errors=[ProblemItem(field="Idempotency-Key", message="reused with a different body")],
        )
    return read_batch(session, batch)


def read_batch(session: Session, batch: Batch) -> BatchRead:
    """The batch with its job."""
    read = BatchRead.model_validate(batch)
    if batch.job_id is not None:
        job = repository.get_job(session, job_id=batch.job_id)
        read.job = None if job is None else JobRead.model_validate(job)
    return read


def checked_associate(associate: AssociateRequest) -> dict[str, Any]:
    """The associator's parameters, validated now so a bad request fails before it is queued."""
    try:
        return parse_params(associate.associator, associate.params).model_dump(mode="json")
    except AssociationError as exc:
        field = "associator" if "unknown associator" in str(exc) else "params"
        raise ApiProblem(
            422, str(exc), errors=[ProblemItem(field=f"associate.{field}", message=str(exc))]
        ) from None


def store_batch(
    session: Session,
    *,
    settings: Settings,
    deployment_id: uuid.UUID,
    detections: Detections,
    source: str,
    associate: AssociateRequest | None,
    idempotency_key: str | None = None,
    request_sha256: str | None = None,
) -> Batch:
    """Insert the batch and, when asked, its job, in the caller's transaction."""
    batch_id = uuid.uuid4()
    job_id = None
    if associate is not None:
        params = checked_associate(associate)
        job = enqueue_job(
            session,
            deployment_id=deployment_id,
            selection={"batch_ids": [str(batch_id)]},
            associator=associate.associator,
            params=params,
            max_attempts=settings.max_attempts,
        )
        job_id = job.id
    return repository.insert_batch(
        session,
        batch_id=batch_id,
        deployment_id=deployment_id,
        detections=detections,
        source=source,
        idempotency_key=idempotency_key,
        request_sha256=request_sha256,
        job_id=job_id,
    )
