"""The queue's state transitions: atomic claims, leases and their rescue, bounded retries,
guarded finishing, cancellation."""

from __future__ import annotations

import threading
import uuid
from collections.abc import Iterator
from datetime import timedelta

import pytest
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association import associate
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.drivers import Listener, driver_for
from roadlink.db.engine import transaction
from roadlink.db.models import JobState, utcnow
from roadlink.queue import (
    ClaimedJob,
    cancel_job,
    claim_next_job,
    complete_job,
    enqueue_job,
    fail_job,
    heartbeat_job,
    rescue_expired_jobs,
)
from roadlink.queue.transitions import FINISHED_CHANNEL, NOTIFY_CHANNEL
from tests.helpers import EnqueueJob


def _claim(sessions: sessionmaker[Session], worker_id: str, **kwargs: object) -> ClaimedJob | None:
    with transaction(sessions) as session:
        return claim_next_job(session, worker_id=worker_id, lease_seconds=30, **kwargs)  # type: ignore[arg-type]


def _state(sessions: sessionmaker[Session], job_id: uuid.UUID) -> tuple[str, int, str | None]:
    with sessions() as session:
        job = repository.get_job(session, job_id=job_id)
        assert job is not None
        return job.state, job.attempts, job.error


def test_concurrent_claims_take_every_job_exactly_once(
    sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    job_ids = {enqueue() for _ in range(24)}
    claimed: list[uuid.UUID] = []
    lock = threading.Lock()

    def drain(worker_id: str) -> None:
        while (job := _claim(sessions, worker_id)) is not None:
            with lock:
                claimed.append(job.id)

    threads = [threading.Thread(target=drain, args=(f"w{k}",)) for k in range(4)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(claimed) == sorted(job_ids)  # none lost, none twice
    assert all(_state(sessions, j)[:2] == ("running", 1) for j in job_ids)


def test_claim_takes_the_oldest_runnable_job(
    sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    first, second = enqueue(), enqueue()
    claimed = _claim(sessions, "w")
    assert claimed is not None and claimed.id == first
    assert claimed.attempts == 1
    # A job whose retry is not yet due is not claimed before its time.
    with transaction(sessions) as session:
        fail_job(session, job=claimed, worker_id="w", error="x", retry=True, backoff_seconds=60)
    assert _claim(sessions, "w").id == second  # type: ignore[union-attr]
    assert _claim(sessions, "w") is None
    later = _claim(sessions, "w", now=utcnow() + timedelta(seconds=61))
    assert later is not None and later.id == first and later.attempts == 2


def test_an_expired_lease_is_rescued_and_its_old_owner_cannot_finish(
    sessions: sessionmaker[Session], enqueue: EnqueueJob, paper_batch: Detections
) -> None:
    job_id = enqueue()
    stalled = _claim(sessions, "stalled")
    assert stalled is not None
    with transaction(sessions) as session:  # the lease has not expired yet: nothing to rescue
        assert rescue_expired_jobs(session) == (0, 0)
    with transaction(sessions) as session:
        assert rescue_expired_jobs(session, now=utcnow() + timedelta(seconds=31)) == (1, 0)
    assert _state(sessions, job_id)[0] == "queued"

    rescuer = _claim(sessions, "rescuer")
    assert rescuer is not None and rescuer.id == job_id and rescuer.attempts == 2
    result = associate(paper_batch, "kmeans++")
    with transaction(sessions) as session:
        assert not heartbeat_job(
            session, job_id=job_id, worker_id="stalled", lease_seconds=30, progress=0.5
        )
        assert not complete_job(
            session, job_id=job_id, worker_id="stalled", result=result, duration_seconds=1.0
        )
    with transaction(sessions) as session:
        assert complete_job(
            session, job_id=job_id, worker_id="rescuer", result=result, duration_seconds=1.0
        )
    with sessions() as session:
        stored = repository.get_job_result(session, job_id=job_id)
        job = repository.get_job(session, job_id=job_id)
    assert stored is not None and job is not None
    assert job.state == "succeeded" and job.lease_owner is None and job.progress == 1.0
    assert stored.matrix_csv == result.to_matrix_csv()


def test_a_lease_expiring_on_the_last_attempt_fails_the_job(
    sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    job_id = enqueue(max_attempts=1)
    assert _claim(sessions, "w") is not None
    with transaction(sessions) as session:
        assert rescue_expired_jobs(session, now=utcnow() + timedelta(seconds=31)) == (0, 1)
    state, attempts, error = _state(sessions, job_id)
    assert (state, attempts) == ("failed", 1)
    assert error is not None and "lease expired" in error


def test_retries_are_bounded_by_max_attempts(
    sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    job_id = enqueue(max_attempts=2)
    outcomes = []
    while (job := _claim(sessions, "w")) is not None:
        with transaction(sessions) as session:
            outcomes.append(
                fail_job(
                    session, job=job, worker_id="w", error="boom", retry=True, backoff_seconds=0
                )
            )
    assert outcomes == [JobState.QUEUED, JobState.FAILED]
    assert _state(sessions, job_id) == ("failed", 2, "boom")


def test_heartbeat_renews_the_lease_and_records_progress(
    sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    job_id = enqueue()
    assert _claim(sessions, "w") is not None
    with transaction(sessions) as session:
        assert heartbeat_job(
            session,
            job_id=job_id,
            worker_id="w",
            lease_seconds=30,
            progress=0.25,
            now=utcnow() + timedelta(seconds=20),
        )
    with transaction(sessions) as session:  # renewed at +20 s: alive at +31 s, not at +51 s
        assert rescue_expired_jobs(session, now=utcnow() + timedelta(seconds=31)) == (0, 0)
    with sessions() as session:
        job = repository.get_job(session, job_id=job_id)
        assert job is not None and job.progress == 0.25


def test_cancelling_stops_queued_and_running_jobs_but_not_finished_ones(
    sessions: sessionmaker[Session], enqueue: EnqueueJob, paper_batch: Detections
) -> None:
    queued, running = enqueue(), enqueue()
    assert _claim(sessions, "w") is not None  # takes `queued`, the oldest
    queued, running = running, queued
    with transaction(sessions) as session:
        assert cancel_job(session, job_id=queued)
        assert cancel_job(session, job_id=running)
        assert not cancel_job(session, job_id=running)  # already cancelled
    assert _state(sessions, queued)[0] == _state(sessions, running)[0] == "cancelled"
    assert _claim(sessions, "w") is None
    with transaction(sessions) as session:  # the worker of the cancelled job can store nothing
        assert not heartbeat_job(
            session, job_id=running, worker_id="w", lease_seconds=30, progress=1
        )
        assert not complete_job(
            session,
            job_id=running,
            worker_id="w",
            result=associate(paper_batch),
            duration_seconds=1.0,
        )
    with sessions() as session:
        assert repository.get_job_result(session, job_id=running) is None


# News of the queue is sent by the transaction that makes it true: delivered at its commit,
# never when it rolls back (PostgreSQL: NOTIFY; SQLite: in-process news and the doorbell).


class Rollback(Exception):
    """Raised to roll a transaction back."""


@pytest.fixture
def listeners(database_url: str) -> Iterator[tuple[Listener, Listener]]:
    """Listeners on both queue channels, listening before the test begins."""
    driver = driver_for(database_url)
    queued, finished = driver.listen(NOTIFY_CHANNEL), driver.listen(FINISHED_CHANNEL)
    for listener in (queued, finished):
        listener.wait(0.0)  # PostgreSQL: the LISTEN connection opens at the first wait
    yield queued, finished
    queued.close()
    finished.close()


def _heard(listener: Listener) -> list[str]:
    """Everything the listener hears within half a second."""
    payloads: list[str] = []
    while (heard := listener.wait(0.5)) is not None:
        payloads += heard
    return payloads


def test_an_enqueue_is_announced_at_commit_only(
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    listeners: tuple[Listener, Listener],
) -> None:
    queued, _ = listeners
    job_id = enqueue()
    assert _heard(queued) == [str(job_id)]
    try:
        with transaction(sessions) as session:
            job = repository.get_job(session, job_id=job_id)
            assert job is not None
            enqueue_job(
                session,
                deployment_id=job.deployment_id,
                selection=job.selection,
                associator="kmeans++",
                params={},
                max_attempts=1,
            )
            raise Rollback
    except Rollback:
        pass
    assert _heard(queued) == []


def test_a_finish_is_announced_at_commit_only(
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    paper_batch: Detections,
    listeners: tuple[Listener, Listener],
) -> None:
    _, finished = listeners
    job_id = enqueue()
    job = _claim(sessions, "w")
    assert job is not None and job.id == job_id
    result = associate(paper_batch)
    try:
        with transaction(sessions) as session:
            assert complete_job(
                session, job_id=job_id, worker_id="w", result=result, duration_seconds=0.1
            )
            raise Rollback
    except Rollback:
        pass
    assert _heard(finished) == []
    with transaction(sessions) as session:
        assert complete_job(
            session, job_id=job_id, worker_id="w", result=result, duration_seconds=0.1
        )
    assert _heard(finished) == [str(job_id)]
