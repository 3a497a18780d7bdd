"""Queue state transitions, each one guarded SQL statement (after procrastinate and River).

Delivery is at least once: a worker that loses its lease (it stalled, or the job was cancelled)
can no longer change the job, because every transition of a running job requires
`state = 'running' AND lease_owner = :me`.

Times that decide who may run a job (run_after, lease expiry, rescue) come from one clock: the
database's `now()` on PostgreSQL, where workers and API replicas run on several hosts whose clocks
drift apart; this host's clock on SQLite, which is embedded and so shared by processes of one host.

Notifications: on PostgreSQL a NOTIFY on `NOTIFY_CHANNEL` (a job is runnable) or
`FINISHED_CHANNEL` (a job finished) is sent in the transaction that makes it true, so it is
delivered at commit and never on rollback. On SQLite the same news reaches the threads of this
process through in-process signals fired after the commit, and the other processes on the
database file through its doorbell (`roadlink.queue.doorbell`), rung after the commit.
"""

from __future__ import annotations

import threading
import uuid
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from datetime import datetime, timedelta
from typing import Any

import orjson
from sqlalchemy import event, func, select, text, update
from sqlalchemy.orm import Session

from roadlink.association.result import AssociationResult
from roadlink.db.json_columns import Selection
from roadlink.db.models import Job, JobResult, JobState, utcnow
from roadlink.queue import doorbell

NOTIFY_CHANNEL = "roadlink_jobs"
"""PostgreSQL channel a NOTIFY is sent on, in the enqueueing transaction, for every new job."""

FINISHED_CHANNEL = "roadlink_jobs_finished"
"""PostgreSQL channel told, in the finishing transaction, the id of every job that finished
(succeeded, failed or cancelled): `?wait=` result requests listen on it."""

# On SQLite there is no NOTIFY: a worker thread in the process that enqueued is woken through
# this event; workers in other processes by the doorbell, or else by polling.
local_enqueue_signal = threading.Event()

# Callbacks given the ids of jobs that finished in this process (SQLite), after the commit.
_local_finish_subscribers: set[Callable[[list[str]], None]] = set()
_subscribers_lock = threading.Lock()

_AFTER_COMMIT = "roadlink_after_commit"


def subscribe_local_finishes(callback: Callable[[list[str]], None]) -> None:
    """Call `callback` with job ids whenever jobs finish in a transaction of this process."""
    with _subscribers_lock:
        _local_finish_subscribers.add(callback)


def unsubscribe_local_finishes(callback: Callable[[list[str]], None]) -> None:
    """Stop calling a callback given to subscribe_local_finishes."""
    with _subscribers_lock:
        _local_finish_subscribers.discard(callback)


def _is_postgres(session: Session) -> bool:
    return session.get_bind().dialect.name == "postgresql"


def _clock(session: Session, now: datetime | None) -> Any:
    """The time a transition is stamped with: `now` when the caller gives one (tests), else the
    database's clock on PostgreSQL (one clock for every host), else this host's clock."""
    if now is not None:
        return now
    return func.now() if _is_postgres(session) else utcnow()


def _after_commit(session: Session, action: Callable[[], None]) -> None:
    """Run `action` once the session's transaction commits (never if it rolls back)."""
    session.info.setdefault(_AFTER_COMMIT, []).append(action)


@event.listens_for(Session, "after_commit")
def _run_after_commit(session: Session) -> None:
    for action in session.info.pop(_AFTER_COMMIT, []):
        action()


@event.listens_for(Session, "after_soft_rollback")
def _drop_after_rollback(session: Session, _previous_transaction: Any) -> None:
    session.info.pop(_AFTER_COMMIT, None)


def _announce_runnable(session: Session, job_id: uuid.UUID | None) -> None:
    """Wake idle workers when this transaction commits."""
    if _is_postgres(session):
        session.execute(
            text("SELECT pg_notify(:channel, :id)"),
            {"channel": NOTIFY_CHANNEL, "id": "" if job_id is None else str(job_id)},
        )
    else:
        database_url = _database_url(session)

        def wake_workers() -> None:
            local_enqueue_signal.set()
            doorbell.ring(database_url, doorbell.QUEUED)

        _after_commit(session, wake_workers)


def _announce_finished(session: Session, job_ids: Iterable[uuid.UUID]) -> None:
    """Tell result waiters that these jobs finished, when this transaction commits."""
    ids = [str(j) for j in job_ids]
    if not ids:
        return
    if _is_postgres(session):
        # One notification per job: a payload is limited to 8000 bytes.
        for job_id in ids:
            session.execute(
                text("SELECT pg_notify(:channel, :id)"),
                {"channel": FINISHED_CHANNEL, "id": job_id},
            )
        return

    def tell_subscribers() -> None:
        with _subscribers_lock:
            subscribers = list(_local_finish_subscribers)
        for callback in subscribers:
            callback(ids)
        doorbell.ring(database_url, doorbell.FINISHED, "\n".join(ids).encode())

    database_url = _database_url(session)
    _after_commit(session, tell_subscribers)


def _database_url(session: Session) -> str:
    return session.get_bind().engine.url.render_as_string(hide_password=False)


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
    )
    if _is_postgres(session):
        # Runnable from the database's now(), the clock claims compare with, not this host's.
        job.created_at = job.run_after = func.now()
    session.add(job)
    session.flush()
    _announce_runnable(session, job.id)
    return job


def has_runnable_job(session: Session, *, now: datetime | None = None) -> bool:
    """Whether a queued job is due: a read, so idle workers polling SQLite take no write lock."""
    now = _clock(session, now)
    query = select(Job.id).where(Job.state == JobState.QUEUED, Job.run_after <= now).limit(1)
    return session.execute(query).first() is not None


def claim_next_job(
    session: Session, *, worker_id: str, lease_seconds: float, now: datetime | None = None
) -> ClaimedJob | None:
    """Atomically take the oldest runnable queued job, or None when there is none.

    One statement on both databases: `UPDATE ... WHERE id = (SELECT ... LIMIT 1) RETURNING`.
    PostgreSQL adds FOR UPDATE SKIP LOCKED, so concurrent workers each take a different job
    without waiting; SQLite serialises writers, so the statement is atomic as it stands.
    The sub-select is compared with `=`, not `IN`: PostgreSQL may run an `IN (...)` sub-select
    once per candidate row, and with SKIP LOCKED each run finds another job, so one claim
    would take them all (the `=` form is evaluated once).
    """
    now = _clock(session, now)
    candidate = (
        select(Job.id)
        .where(Job.state == JobState.QUEUED, Job.run_after <= now)
        .order_by(Job.run_after, Job.created_at)
        .limit(1)
        .with_for_update(skip_locked=True)
    )
    statement = (
        update(Job)
        .where(Job.id == candidate.scalar_subquery(), Job.state == JobState.QUEUED)
        .values(
            state=JobState.RUNNING,
            lease_owner=worker_id,
            lease_expires_at=now + timedelta(seconds=lease_seconds),
            attempts=Job.attempts + 1,
            started_at=now,
            progress=0.0,
        )
        .returning(
            Job.id,
            Job.deployment_id,
            Job.selection,
            Job.associator,
            Job.params,
            Job.attempts,
            Job.max_attempts,
        )
        .execution_options(synchronize_session=False)
    )
    row = session.execute(statement).first()
    return None if row is None else ClaimedJob(*row)


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
    now = _clock(session, now)
    statement = (
        update(Job)
        .where(_running_as(job_id, worker_id))
        .values(
            state=JobState.SUCCEEDED,
            progress=1.0,
            finished_at=now,
            duration_seconds=duration_seconds,
            n_detections=len(result.detections),
            lease_owner=None,
            lease_expires_at=None,
            error=None,
        )
        .execution_options(synchronize_session=False)
    )
    if session.execute(statement).rowcount != 1:  # type: ignore[attr-defined]
        return False
    session.add(
        JobResult(
            job_id=job_id,
            result_json=orjson.dumps(result.to_dict()).decode(),
            matrix_csv=result.to_matrix_csv(),
            accuracy=None if result.metrics is None else result.metrics.accuracy,
            created_at=now,
        )
    )
    session.flush()
    _announce_finished(session, [job_id])
    return True


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
