"""Queue state transitions, each one guarded SQL statement (after procrastinate and River).

Delivery is at least once: a worker that loses its lease (it stalled, or the job was cancelled)
can no longer change the job, because every transition of a running job requires
`state = 'running' AND lease_owner = :me`.

Times that decide who may run a job (run_after, lease expiry, rescue) come from one clock, and
news of the queue (a job is runnable, jobs finished) is sent by the transaction that makes it
true, delivered at its commit and never on rollback: both as the database's driver does them
(`roadlink.db.drivers`).
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any, cast

from sqlalchemy import Interval, Table, bindparam, insert, select, update
from sqlalchemy.orm import Session

from roadlink.association.result import AssociationResult
from roadlink.association.result_text import result_json_compact
from roadlink.db.drivers import Driver, driver_of, prebuilt
from roadlink.db.json_columns import Selection
from roadlink.db.models import Job, JobResult, JobState
from roadlink.logs import current_request_id
from roadlink.queue.webhooks import record_job_finished

NOTIFY_CHANNEL = "roadlink_jobs"
"""Channel told, when the transaction commits, of every job that becomes runnable (its id, or
nothing for a rescue): idle workers listen on it."""

FINISHED_CHANNEL = "roadlink_jobs_finished"
"""Channel told, when the transaction commits, the id of every job that finished (succeeded,
failed or cancelled): `?wait=` result requests listen on it."""


def _clock(session: Session, now: datetime | None) -> Any:
    """The time a transition is stamped with: `now` when the caller gives one (tests), else the
    driver's clock (the database's on PostgreSQL, one for every host; this host's on SQLite)."""
    return driver_of(session).clock() if now is None else now


_JOB = cast(Table, Job.__table__)
_RESULT = cast(Table, JobResult.__table__)


def _announce_runnable(session: Session, job_id: uuid.UUID | None) -> None:
    """Wake idle workers when this transaction commits."""
    payload = "" if job_id is None else str(job_id)
    driver_of(session).notify(session, NOTIFY_CHANNEL, [payload])


def _announce_finished(session: Session, job_ids: Iterable[uuid.UUID]) -> None:
    """Tell result waiters that these jobs finished, when this transaction commits, and put
    their `job.finished` webhook events in the outbox, in this transaction."""
    finished = list(job_ids)
    if finished:
        driver_of(session).notify(session, FINISHED_CHANNEL, [str(j) for j in finished])
        record_job_finished(session, finished)


@dataclass(frozen=True)
class ClaimedJob:
    """What a worker needs from the job it claimed."""

    id: uuid.UUID
    deployment_id: uuid.UUID
    selection: Selection
    associator: str
    params: dict[str, Any]
    attempts: int
    max_attempts: int
    request_id: str | None = None


def enqueue_job(
    session: Session,
    *,
    deployment_id: uuid.UUID,
    selection: Selection,
    associator: str,
    params: dict[str, Any],
    max_attempts: int,
    job_id: uuid.UUID | None = None,
) -> Job:
    """Add a queued job in the caller's transaction; workers are told when it commits."""
    job = Job(
        id=job_id or uuid.uuid4(),
        deployment_id=deployment_id,
        selection=selection,
        associator=associator,
        params=params,
        state=JobState.QUEUED,
        max_attempts=max_attempts,
        # The request this is done for, if any: the worker logs the job under its id.
        request_id=current_request_id(),
        # Set, though NULL, so that the new row is whole in the session: a response that shows
        # the job (a batch's with `associate`) then reads nothing back before its commit.
        lease_owner=None,
        lease_expires_at=None,
        error=None,
        started_at=None,
        finished_at=None,
        duration_seconds=None,
        n_detections=None,
    )
    # Runnable from the clock claims compare with (on PostgreSQL the database's, not this host's).
    job.created_at = job.run_after = driver_of(session).clock()
    session.add(job)
    session.flush()
    _announce_runnable(session, job.id)
    return job


def has_runnable_job(session: Session, *, now: datetime | None = None) -> bool:
    """Whether a queued job is due: a read, so idle workers polling SQLite take no write lock."""
    query, params = prebuilt(session, "due", _build_due, now=now)
    return session.connection().execute(query, params).first() is not None


def _build_due(driver: Driver, now: Any, bound: bool) -> Any:
    return (
        select(_JOB.c.id).where(_JOB.c.state == JobState.QUEUED, _JOB.c.run_after <= now).limit(1)
    )


def claim_next_job(
    session: Session, *, worker_id: str, lease_seconds: float, now: datetime | None = None
) -> ClaimedJob | None:
    """Atomically take the oldest runnable queued job, or None when there is none.

    One statement on both databases: `UPDATE ... WHERE id = (SELECT ... LIMIT 1) RETURNING`.
    The driver locks the candidate: PostgreSQL adds FOR UPDATE SKIP LOCKED, so concurrent
    workers each take a different job without waiting; SQLite serialises writers, so the
    statement is atomic as it stands.
    The sub-select is compared with `=`, not `IN`: PostgreSQL may run an `IN (...)` sub-select
    once per candidate row, and with SKIP LOCKED each run finds another job, so one claim
    would take them all (the `=` form is evaluated once).
    """
    statement, params = prebuilt(session, "claim", _build_claim, now=now)
    lease = timedelta(seconds=lease_seconds)
    params |= {"worker_id": worker_id}
    params |= {"expires": params["now"] + lease} if "now" in params else {"lease": lease}
    row = session.connection().execute(statement, params).first()
    return None if row is None else ClaimedJob(*row)


def _build_claim(driver: Driver, now: Any, bound: bool) -> Any:
    job = _JOB.c
    candidate = driver.lock_for_claim(
        select(job.id)
        .where(job.state == JobState.QUEUED, job.run_after <= now)
        .order_by(job.run_after, job.created_at)
        .limit(1)
    )
    # A bound clock's expiry is worked out here; the database's clock adds the lease itself.
    expires = (
        bindparam("expires", type_=job.lease_expires_at.type)
        if bound
        else now + bindparam("lease", type_=Interval())
    )
    return (
        update(_JOB)
        .where(job.id == candidate.scalar_subquery(), job.state == JobState.QUEUED)
        .values(
            state=JobState.RUNNING,
            lease_owner=bindparam("worker_id"),
            lease_expires_at=expires,
            attempts=job.attempts + 1,
            started_at=now,
            progress=0.0,
        )
        .returning(
            job.id,
            job.deployment_id,
            job.selection,
            job.associator,
            job.params,
            job.attempts,
            job.max_attempts,
            job.request_id,
        )
    )


def _running_as(job_id: uuid.UUID, worker_id: str) -> Any:
    return (Job.id == job_id) & (Job.state == JobState.RUNNING) & (Job.lease_owner == worker_id)


def heartbeat_job(
    session: Session,
    *,
    job_id: uuid.UUID,
    worker_id: str,
    lease_seconds: float,
    progress: float,
    now: datetime | None = None,
) -> bool:
    """Renew the lease and record progress; False when the job is no longer this worker's."""
    now = _clock(session, now)
    statement = (
        update(Job)
        .where(_running_as(job_id, worker_id))
        .values(lease_expires_at=now + timedelta(seconds=lease_seconds), progress=progress)
        .execution_options(synchronize_session=False)
    )
    return session.execute(statement).rowcount == 1  # type: ignore[attr-defined]


def complete_job(
    session: Session,
    *,
    job_id: uuid.UUID,
    worker_id: str,
    result: AssociationResult,
    duration_seconds: float,
    now: datetime | None = None,
) -> bool:
    """Mark the job succeeded and store its result, both or neither; False if not ours any more."""
    statement, params = prebuilt(session, "succeed", _build_succeed, now=now)
    params |= {"job_id": job_id, "worker_id": worker_id}
    connection = session.connection()
    finished = params | {"duration": duration_seconds, "n_detections": len(result.detections)}
    if connection.execute(statement, finished).rowcount != 1:
        return False
    statement, _ = prebuilt(session, "result", _build_result, now=now)
    stored = params | {
        # orjson.dumps(result.to_dict()), the same text, without a dict per detection.
        "result_json": result_json_compact(result),
        "matrix_csv": result.to_matrix_csv(),
        "accuracy": None if result.metrics is None else result.metrics.accuracy,
    }
    connection.execute(statement, stored)
    _announce_finished(session, [job_id])
    return True


def _build_succeed(driver: Driver, now: Any, bound: bool) -> Any:
    job = _JOB.c
    return (
        update(_JOB)
        .where(
            job.id == bindparam("job_id"),
            job.state == JobState.RUNNING,
            job.lease_owner == bindparam("worker_id"),
        )
        .values(
            state=JobState.SUCCEEDED,
            progress=1.0,
            finished_at=now,
            duration_seconds=bindparam("duration", type_=job.duration_seconds.type),
            n_detections=bindparam("n_detections", type_=job.n_detections.type),
            lease_owner=None,
            lease_expires_at=None,
            error=None,
        )
    )


def _build_result(driver: Driver, now: Any, bound: bool) -> Any:
    result = _RESULT.c
    return insert(_RESULT).values(
        job_id=bindparam("job_id", type_=result.job_id.type),
        result_json=bindparam("result_json", type_=result.result_json.type),
        matrix_csv=bindparam("matrix_csv", type_=result.matrix_csv.type),
        accuracy=bindparam("accuracy", type_=result.accuracy.type),
        created_at=now,
    )


def fail_job(
    session: Session,
    *,
    job: ClaimedJob,
    worker_id: str,
    error: str,
    retry: bool,
    backoff_seconds: float,
    now: datetime | None = None,
) -> JobState | None:
    """Record a failed run: queued again after a backoff while attempts remain and `retry`,
    otherwise failed. Returns the new state, or None when the job is no longer this worker's."""
    now = _clock(session, now)
    again = retry and job.attempts < job.max_attempts
    values: dict[str, Any] = {"lease_owner": None, "lease_expires_at": None, "error": error}
    if again:
        delay = backoff_seconds * 2 ** (job.attempts - 1)
        values |= {"state": JobState.QUEUED, "run_after": now + timedelta(seconds=delay)}
    else:
        values |= {"state": JobState.FAILED, "finished_at": now}
    statement = (
        update(Job)
        .where(_running_as(job.id, worker_id))
        .values(**values)
        .execution_options(synchronize_session=False)
    )
    if session.execute(statement).rowcount != 1:  # type: ignore[attr-defined]
        return None
    if again:
        return JobState.QUEUED
    _announce_finished(session, [job.id])
    return JobState.FAILED


def release_job(session: Session, *, job_id: uuid.UUID, worker_id: str) -> bool:
    """Give a running job back to the queue without spending an attempt (worker shutdown)."""
    statement = (
        update(Job)
        .where(_running_as(job_id, worker_id))
        .values(
            state=JobState.QUEUED,
            attempts=Job.attempts - 1,
            lease_owner=None,
            lease_expires_at=None,
            progress=0.0,
            run_after=_clock(session, None),
        )
        .execution_options(synchronize_session=False)
    )
    released = session.execute(statement).rowcount == 1  # type: ignore[attr-defined]
    if released:
        _announce_runnable(session, job_id)
    return released


def cancel_job(session: Session, *, job_id: uuid.UUID, now: datetime | None = None) -> bool:
    """Cancel a queued or running job; False when it had already finished.

    A running job's worker notices at its next heartbeat or progress report, stops, and cannot
    store a result (its guarded transitions no longer match).
    """
    now = _clock(session, now)
    statement = (
        update(Job)
        .where(Job.id == job_id, Job.state.in_([JobState.QUEUED, JobState.RUNNING]))
        .values(
            state=JobState.CANCELLED,
            finished_at=now,
            lease_owner=None,
            lease_expires_at=None,
        )
        .execution_options(synchronize_session=False)
    )
    cancelled = session.execute(statement).rowcount == 1  # type: ignore[attr-defined]
    if cancelled:
        _announce_finished(session, [job_id])
    return cancelled


def rescue_expired_jobs(session: Session, *, now: datetime | None = None) -> tuple[int, int]:
    """Running jobs whose lease expired (their worker died or stalled): queued again while
    attempts remain, failed with the reason otherwise. Returns (requeued, failed)."""
    now = _clock(session, now)
    expired = (Job.state == JobState.RUNNING) & (Job.lease_expires_at < now)
    failed_ids = session.scalars(
        update(Job)
        .where(expired, Job.attempts >= Job.max_attempts)
        .values(
            state=JobState.FAILED,
            finished_at=now,
            lease_owner=None,
            lease_expires_at=None,
            error="the worker running this job stopped responding (its lease expired) "
            "on its last allowed attempt",
        )
        .returning(Job.id)
        .execution_options(synchronize_session=False)
    ).all()
    requeued = session.execute(
        update(Job)
        .where(expired, Job.attempts < Job.max_attempts)
        .values(
            state=JobState.QUEUED,
            lease_owner=None,
            lease_expires_at=None,
            error="the worker running this job stopped responding (its lease expired); retried",
        )
        .execution_options(synchronize_session=False)
    ).rowcount  # type: ignore[attr-defined]
    if requeued:
        _announce_runnable(session, None)
    _announce_finished(session, failed_ids)
    return int(requeued), len(failed_ids)
