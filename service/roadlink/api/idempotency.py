"""Idempotent job creation (`Idempotency-Key` on POST /v1/jobs), and forgetting old keys.

The semantics are those of batch uploads: a retry with the same key and the same body gets the
job the first request created (`Idempotent-Replayed: true`) and enqueues nothing; the same key
with a different body is a 422. Job keys belong to the API key that sent them, so two clients
cannot collide on "1". Keys of batches and jobs are forgotten after ROADLINK_IDEMPOTENCY_HOURS
by a task of each API process.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
import uuid
from collections.abc import AsyncIterator, Callable
from datetime import timedelta
from typing import Annotated, TypeVar

from fastapi import FastAPI, Header, Response
from pydantic import BaseModel
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker
from starlette.concurrency import run_in_threadpool

from roadlink.api.errors import ApiProblem, ProblemItem
from roadlink.api.schemas import JobRead
from roadlink.api.tasks import in_background
from roadlink.db import repository
from roadlink.db.engine import transaction
from roadlink.db.idempotency import (
    Forgotten,
    find_job_idempotency_key,
    forget_idempotency_keys,
    record_job_idempotency_key,
)
from roadlink.db.models import utcnow
from roadlink.settings import Settings

log = logging.getLogger("roadlink")

Written = TypeVar("Written")
Found = TypeVar("Found")

# How often an API process forgets expired keys; keys live between the retention and this more.
FORGET_EVERY_SECONDS = 3600.0

IdempotencyKeyHeader = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=200,
        description="Makes retries safe: a repeated request with the same key (from the same API "
        "key) returns the job the first one created; the same key with a different body is an "
        "error (422). Keys are remembered for at least 24 hours.",
    ),
]


def request_sha256(body: BaseModel) -> str:
    """A digest of the request as parsed (so whitespace or key order do not make it differ)."""
    return hashlib.sha256(body.model_dump_json().encode()).hexdigest()


def replayed_job(
    session: Session, *, principal: str, idempotency_key: str, digest: str, response: Response
) -> JobRead | None:
    """The job an earlier request with this key created (its state now), None if there was
    none; 422 when the key came with another body."""
    earlier = find_job_idempotency_key(
        session, principal=principal, idempotency_key=idempotency_key
    )
    if earlier is None:
        return None
    if earlier.request_sha256 != digest:
        raise ApiProblem(
            422,
            f"Idempotency-Key '{idempotency_key}' was used for a different request "
            f"(job {earlier.job_id}); use a new key for a new job",
            errors=[ProblemItem(field="Idempotency-Key", message="reused with a different body")],
        )
    job = repository.get_job(session, job_id=earlier.job_id)
    if job is None:  # the record is deleted with its job (ON DELETE CASCADE)
        return None
    response.headers["Idempotent-Replayed"] = "true"
    return JobRead.model_validate(job)


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


@contextlib.asynccontextmanager
async def forgetting_expired_keys(app: FastAPI) -> AsyncIterator[None]:
    """A lifespan: while the app runs, forget expired Idempotency-Keys every hour."""

    async def loop() -> None:
        while True:
            try:
                forgotten = await run_in_threadpool(
                    forget_expired_keys, app.state.sessions, app.state.settings
                )
                if forgotten.batches or forgotten.jobs:
                    log.info(
                        "forgot the Idempotency-Keys of %d batch(es) and %d job(s)",
                        forgotten.batches,
                        forgotten.jobs,
                    )
            except Exception:  # a busy or unmigrated database: try again next round
                log.warning("could not forget expired Idempotency-Keys", exc_info=True)
            await asyncio.sleep(FORGET_EVERY_SECONDS)

    async with in_background(loop()):
        yield
