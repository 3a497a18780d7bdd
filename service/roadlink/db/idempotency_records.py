"""Where each endpoint keeps its Idempotency-Keys, and forgetting them once they are old.

A key is scoped by its sender (the principal: an API key's id, or "anonymous") and its
endpoint. A deployment's batches keep theirs on the batch row (unique per deployment and
principal); jobs have the `job_idempotency_key` table (unique per principal). Both are
remembered for at least ROADLINK_IDEMPOTENCY_HOURS (24 by default), then forgotten, so the
tables do not grow forever.
"""

from __future__ import annotations

import uuid
from dataclasses import dataclass
from datetime import datetime

from sqlalchemy import delete, select, update
from sqlalchemy.orm import Session

from roadlink.db.models import Batch, JobIdempotencyKey


@dataclass(frozen=True)
class Forgotten:
    """How many Idempotency-Keys a clean-up forgot."""

    batches: int
    jobs: int


def find_batch_idempotency_key(
    session: Session, *, deployment_id: uuid.UUID, principal: str, idempotency_key: str
) -> Batch | None:
    """The batch `principal` created earlier with this key in this deployment, if any."""
    query = select(Batch).where(
        Batch.deployment_id == deployment_id,
        Batch.idempotency_principal == principal,
        Batch.idempotency_key == idempotency_key,
    )
    return session.scalars(query).first()


def find_job_idempotency_key(
    session: Session, *, principal: str, idempotency_key: str
) -> JobIdempotencyKey | None:
    """The record of a job created earlier by `principal` with this key, if any."""
    return session.get(JobIdempotencyKey, (principal, idempotency_key))


def record_job_idempotency_key(
    session: Session,
    *,
    principal: str,
    idempotency_key: str,
    request_sha256: str,
    job_id: uuid.UUID,
) -> None:
    """Remember which job this key created, in the caller's transaction (with the job)."""
    session.add(
        JobIdempotencyKey(
            principal=principal,
            idempotency_key=idempotency_key,
            request_sha256=request_sha256,
            job_id=job_id,
        )
    )
    session.flush()


def forget_idempotency_keys(session: Session, *, created_before: datetime) -> Forgotten:
    """Forget the Idempotency-Keys of batches and jobs created before `created_before`.

    A batch keeps its detections; only its key is cleared, so the same key may be used again.
    """
    batches = session.execute(
        update(Batch)
        .where(Batch.idempotency_key.is_not(None), Batch.created_at < created_before)
        .values(idempotency_key=None, idempotency_principal=None, request_sha256=None)
    )
    jobs = session.execute(
        delete(JobIdempotencyKey).where(JobIdempotencyKey.created_at < created_before)
    )
    return Forgotten(
        batches=int(batches.rowcount),  # type: ignore[attr-defined]
        jobs=int(jobs.rowcount),  # type: ignore[attr-defined]
    )
