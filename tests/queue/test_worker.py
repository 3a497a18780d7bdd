"""The worker: runs the core on a claimed job and stores exactly what the core returns; retries
crashes, not user errors; stops when its job is cancelled; hands its job back when stopping."""

from __future__ import annotations

import json
import threading
import time
import uuid
from collections.abc import Iterator
from typing import Any

import pytest
from sqlalchemy.orm import Session, sessionmaker

from service.association import associate
from service.association.detections import Detections
from service.db import repository
from service.db.models import Job
from service.queue import worker as worker_module
from service.queue.worker import Worker
from service.settings import Settings
from tests.queue.conftest import EnqueueJob


def _job(sessions: sessionmaker[Session], job_id: uuid.UUID) -> Job:
    with sessions() as session:
        job = repository.get_job(session, job_id=job_id)
        assert job is not None
        return job


def _wait_for(condition: Any, timeout: float = 10.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


@pytest.fixture
def slow_associate(monkeypatch: pytest.MonkeyPatch) -> Iterator[threading.Event]:
    """Replace the core with one that reports progress every 10 ms for up to 10 s, so tests can
    act on a job while it runs; the event is set once it started."""
    started = threading.Event()

    def run(detections: Detections, associator: str, params: Any, progress: Any) -> Any:
        started.set()
        for step in range(1000):
            progress(step / 1000)
            time.sleep(0.01)
        raise AssertionError("the job was not interrupted")

    monkeypatch.setattr(worker_module, "associate", run)
    yield started


def test_a_job_stores_exactly_what_the_core_computes(
    worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob, paper_batch: Detections
) -> None:
    job_id = enqueue("kmeans", {"seed": 4, "n_init": 3})
    assert worker.run_once()
    assert not worker.run_once()  # nothing else queued
    job = _job(sessions, job_id)
    assert (job.state, job.attempts, job.progress, job.n_detections) == ("succeeded", 1, 1.0, 100)
    with sessions() as session:
        stored = repository.get_job_result(session, job_id=job_id)
    assert stored is not None
    expected = associate(paper_batch, "kmeans", {"seed": 4, "n_init": 3})
    assert json.loads(stored.result_json) == json.loads(json.dumps(expected.to_dict()))
    assert stored.matrix_csv == expected.to_matrix_csv()


def test_a_crash_is_retried_until_attempts_run_out(
    worker: Worker,
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    def crash(*_args: Any, **_kwargs: Any) -> Any:
        raise RuntimeError("out of memory")

    monkeypatch.setattr(worker_module, "associate", crash)
    job_id = enqueue(max_attempts=2)
    assert worker.run_once()
    assert _job(sessions, job_id).state == "queued"
    assert worker.run_once()
    job = _job(sessions, job_id)
    assert (job.state, job.attempts) == ("failed", 2)
    assert job.error is not None and "RuntimeError: out of memory" in job.error


def test_a_user_error_fails_at_once_with_the_cores_message(
    worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob, paper_batch: Detections
) -> None:
    job_id = enqueue("svm-linear", detections=paper_batch.without_labels())
    assert worker.run_once()
    job = _job(sessions, job_id)
    assert (job.state, job.attempts) == ("failed", 1)
    assert job.error is not None and "label" in job.error


def test_progress_is_reported_and_a_cancelled_job_stops(
    settings: Settings,
    worker: Worker,
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    slow_associate: threading.Event,
) -> None:
    from service.db.engine import transaction
    from service.queue import cancel_job

    job_id = enqueue()
    runner = threading.Thread(target=worker.run_once)
    runner.start()
    assert slow_associate.wait(10)
    _wait_for(lambda: _job(sessions, job_id).progress > 0)  # written by the heartbeat
    with transaction(sessions) as session:
        assert cancel_job(session, job_id=job_id)
    cancelled_at = time.monotonic()
    runner.join(10)
    assert not runner.is_alive()
    # Noticed at the next heartbeat, then stopped at the next progress report.
    assert time.monotonic() - cancelled_at < settings.heartbeat_seconds + 1.0
    assert _job(sessions, job_id).state == "cancelled"
    with sessions() as session:
        assert repository.get_job_result(session, job_id=job_id) is None


def test_a_stopping_worker_hands_its_job_back(
    worker: Worker,
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    slow_associate: threading.Event,
) -> None:
    job_id = enqueue()
    runner = threading.Thread(target=worker.run_once)
    runner.start()
    assert slow_associate.wait(10)
    worker.stopping.set()
    runner.join(10)
    job = _job(sessions, job_id)
    assert (job.state, job.attempts, job.lease_owner) == ("queued", 0, None)


def test_an_idle_worker_wakes_for_a_new_job(
    settings: Settings, worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    """By NOTIFY on PostgreSQL; on SQLite by the in-process signal (else by polling)."""
    runner = threading.Thread(target=worker.run)
    runner.start()
    try:
        time.sleep(0.2)  # idle and waiting
        job_id = enqueue()
        _wait_for(lambda: _job(sessions, job_id).state == "succeeded")
    finally:
        worker.stopping.set()
        runner.join(10)
    assert not runner.is_alive()
