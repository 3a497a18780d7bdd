"""Idempotency-Keys: a retry with the same key and the same body gets what the first request
created and creates nothing; the same key with a different body is a 422. Concurrent copies of
one request: the first commit wins. Keys are forgotten after ROADLINK_IDEMPOTENCY_HOURS.

Batch keys live on the batch row (unique per deployment); job keys in their own table (unique
per API key, so two clients cannot collide on "1"): `db/idempotency_records.py`.

Why batches and jobs do not share one rule for the header, the scope and the digest: each
difference is visible to clients, and the redesign changes no response.
- The header: on batches it has max_length=200 only (an empty key is a key), on jobs also
  min_length=1 (an empty key is a 422); the two descriptions differ too, in openapi.json.
- The scope: a batch key is unique per deployment, whichever API key sends it; a job key per
  API key. One key from two API keys replays a batch but makes two jobs.
- The digest: a batch's covers its content type and raw bytes (the CSV or JSON text as sent),
  a job's its parsed body (`request_sha256` in `api/routers/jobs.py`), so whitespace and key order
  tell batch retries apart, not job retries.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable
from datetime import timedelta
from typing import TypeVar

from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db import repository
from roadlink.db.engine import transaction
from roadlink.db.idempotency_records import (
    Forgotten,
    find_job_idempotency_key,
    forget_idempotency_keys,
    record_job_idempotency_key,
)
from roadlink.db.models import Batch, Job, utcnow
from roadlink.services.problems import ProblemItem, ServiceProblem
from roadlink.settings import Settings

Written = TypeVar("Written")
Found = TypeVar("Found")


def first_commit_wins(
    session: Session, write: Callable[[], Written], earlier: Callable[[], Found | None]
) -> Written | Found:
    """Write and commit; when a concurrent request with the same Idempotency-Key committed
    first, answer what that request created instead.

    Batches and jobs alike: their keys are unique in the database, so of several requests with
    one key sent at once, exactly one commits and the others meet the unique constraint (when
    writing or when committing). Each of those rolls back and returns `earlier()`, the winner's
    answer (or the 422 of a different body), as a retry after the fact would get it.
    """
    try:
        written = write()
        session.commit()
        return written
    except IntegrityError:
        session.rollback()
        found = earlier()
        if found is None:  # some other constraint: the error handler answers it
            raise
        return found


def replayed_batch(batch: Batch, digest: str) -> Batch:
    """The batch a repeated request created, or 422 if the key came with another body."""
    _same_body(
        batch.request_sha256, digest, batch.idempotency_key, f"batch {batch.id}", "new detections"
    )
    return batch


def replayed_job(
    session: Session, *, principal: str, idempotency_key: str, digest: str
) -> Job | None:
    """The job an earlier request with this key created (its state now), None if there was
    none; 422 when the key came with another body."""
    earlier = find_job_idempotency_key(
        session, principal=principal, idempotency_key=idempotency_key
    )
    if earlier is None:
        return None
    _same_body(
        earlier.request_sha256, digest, idempotency_key, f"job {earlier.job_id}", "a new job"
    )
    # None when the job is gone: the record is deleted with its job (ON DELETE CASCADE).
    return repository.get_job(session, job_id=earlier.job_id)


def _same_body(
    recorded: str | None, digest: str, idempotency_key: str | None, created: str, new_thing: str
) -> None:
    """422 when a key comes again with a body other than the one it was first used with."""
    if recorded != digest:
        raise ServiceProblem(
            422,
            f"Idempotency-Key '{idempotency_key}' was used for a different request "
            f"({created}); use a new key for {new_thing}",
            errors=[ProblemItem(field="Idempotency-Key", message="reused with a different body")],
        )


def record_job_key(
    session: Session, *, job_id: uuid.UUID, principal: str, idempotency_key: str | None, digest: str
) -> None:
    """Remember which job this key created, in the job's transaction."""
    if idempotency_key is not None:
        record_job_idempotency_key(
            session,
            principal=principal,
            idempotency_key=idempotency_key,
            request_sha256=digest,
            job_id=job_id,
        )


def forget_expired_keys(sessions: sessionmaker[Session], settings: Settings) -> Forgotten:
    """Forget the Idempotency-Keys older than the retention (ROADLINK_IDEMPOTENCY_HOURS)."""
    cutoff = utcnow() - timedelta(hours=settings.idempotency_hours)
    with transaction(sessions) as session:
        return forget_idempotency_keys(session, created_before=cutoff)
