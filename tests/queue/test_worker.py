"""The worker: runs the core on a claimed job and stores exactly what the core returns; retries
crashes, not user errors; stops when its job is cancelled; hands its job back when stopping;
kills a job past its time limit and goes on to the next (scaled out: `test_scaleout`)."""

from __future__ import annotations

import multiprocessing
import os
import threading
import time
import uuid
from typing import Any

import orjson
import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association import associate
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import transaction
from roadlink.db.models import Job
from roadlink.queue.worker import Worker, run_worker_process
from roadlink.settings import Settings
from tests.helpers import EnqueueJob

pytestmark = pytest.mark.usefixtures("test_associators")


def _job(sessions: sessionmaker[Session], job_id: uuid.UUID) -> Job:
    with sessions() as session:
        job = repository.get_job(session, job_id=job_id)
        assert job is not None
        return job


def _wait_for(condition: Any, timeout: float = 60.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert time.monotonic() < deadline, "timed out"
        time.sleep(0.01)


# Reports progress every 10 ms for 10 s, so that tests can act on the job while it runs.
SLOW = {"seconds": 10.0}


def _wait_until_running(sessions: sessionmaker[Session], job_id: uuid.UUID) -> None:
    """Until the job runs and its progress reached the database (through the heartbeat)."""
    _wait_for(lambda: _job(sessions, job_id).progress > 0)


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
    # The text the API serves as is: orjson's of the row objects, byte for byte.
    assert stored.result_json == orjson.dumps(expected.to_dict()).decode()
    assert stored.matrix_csv == expected.to_matrix_csv()


def _pool_worker_niceness(settings: Settings, answer: Any) -> None:
    """A worker process as a pool starts it, answering its niceness instead of working."""
    from roadlink.queue import worker as module

    module.Worker.run = lambda self: answer.put(os.nice(0))  # type: ignore[method-assign]
    run_worker_process(settings, parent_pid=os.getppid())


@pytest.mark.parametrize("niceness", [0, 7])
def test_a_pool_worker_runs_as_much_below_its_parent_as_the_setting_says(
    settings: Settings, niceness: int
) -> None:
    spawn = multiprocessing.get_context("spawn")
    answer = spawn.Queue()
    process = spawn.Process(
        target=_pool_worker_niceness,
        args=(settings.model_copy(update={"worker_niceness": niceness}), answer),
    )
    process.start()
    try:
        assert answer.get(timeout=60) == min(os.nice(0) + niceness, 19)
    finally:
        process.join(60)


def test_a_crash_fails_at_once_with_a_short_error_and_the_traceback_in_the_log(
    worker: Worker,
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    caplog: pytest.LogCaptureFixture,
) -> None:
    """The core is deterministic: a job it fails on would fail again, so it is not retried. Its
    error, which any key that may read the job sees, names the failure without internals; the
    traceback goes to the log, under the error id the job's error gives."""
    job_id = enqueue("test-crashing", max_attempts=3)
    assert worker.run_once()
    job = _job(sessions, job_id)
    assert (job.state, job.attempts) == ("failed", 1)
    assert job.error is not None
    assert job.error.startswith("the associator failed: RuntimeError: out of memory (error id ")
    assert "Traceback" not in job.error and ".py" not in job.error and "\n" not in job.error
    error_id = job.error.rsplit("error id ", 1)[1].rstrip(")")
    logged = [r.getMessage() for r in caplog.records if error_id in r.getMessage()]
    assert logged and "Traceback" in logged[0] and "associators_for_tests.py" in logged[0]


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
) -> None:
    from roadlink.queue import cancel_job

    job_id = enqueue("test-sleeping", SLOW)
    runner = threading.Thread(target=worker.run_once)
    runner.start()
    _wait_until_running(sessions, job_id)
    with transaction(sessions) as session:
        assert cancel_job(session, job_id=job_id)
    cancelled_at = time.monotonic()
    runner.join(10)
    assert not runner.is_alive()
    # Noticed at the next heartbeat, then stopped at the next progress report.
    assert time.monotonic() - cancelled_at < settings.heartbeat_seconds + 1.0
    assert worker.associator_process.pid is not None  # stopped politely, not killed
    assert _job(sessions, job_id).state == "cancelled"
    with sessions() as session:
        assert repository.get_job_result(session, job_id=job_id) is None


def test_a_stopping_worker_hands_its_job_back(
    worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    job_id = enqueue("test-sleeping", SLOW)
    runner = threading.Thread(target=worker.run_once)
    runner.start()
    _wait_until_running(sessions, job_id)
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


def test_a_worker_woken_for_several_jobs_takes_one_and_passes_on_the_others(
    worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    """On SQLite a ring wakes one idle worker: it hands what else the ring named to another
    before it runs the job it took."""
    jobs: list[uuid.UUID] = []
    passed: list[list[str]] = []
    states: list[list[str]] = []

    class Wakeup:
        def wait(self, timeout: float) -> list[str]:
            if not jobs:  # the first wait: two jobs come, and are heard of together
                jobs.extend([enqueue(), enqueue()])
                return [str(j) for j in jobs] + [""]
            worker.stopping.set()
            return []

        def pass_on(self, news: list[str]) -> None:
            passed.append(news)
            states.append([_job(sessions, j).state for j in jobs])

        def close(self) -> None:
            pass

    worker.run(Wakeup())
    # Passed on once the first is claimed, before it runs; no other worker took the second, so
    # this one ran it next (with nothing heard to pass on).
    assert (passed, states) == ([[str(jobs[1]), ""]], [["running", "queued"]])
    assert [_job(sessions, j).state for j in jobs] == ["succeeded", "succeeded"]


@pytest.mark.parametrize("report_progress", [True, False], ids=["reporting", "stuck"])
def test_a_job_past_its_time_limit_fails_and_the_worker_takes_the_next(
    settings: Settings,
    engine: Engine,
    sessions: sessionmaker[Session],
    enqueue: EnqueueJob,
    paper_batch: Detections,
    report_progress: bool,
) -> None:
    """Whether or not the associator still reports progress, its process is killed at the
    limit; the worker survives it and runs the next job in a new associator process."""
    worker = Worker(settings.model_copy(update={"job_timeout_seconds": 0.5}), engine=engine)
    try:
        slow = enqueue("test-sleeping", {"seconds": 30.0, "report_progress": report_progress})
        following = enqueue("kmeans++")
        began = time.monotonic()
        assert worker.run_once()
        took = time.monotonic() - began
        first_child = worker.associator_process.pid
        assert first_child is None  # killed with its job
        job = _job(sessions, slow)
        assert (job.state, job.attempts) == ("failed", 1)  # not retried: it would overrun again
        assert job.error is not None and "exceeded the time limit of 0.5 s" in job.error
        # Stopped at the limit, not after the job's 30 s. The limit counts the association only,
        # so a slow cold start of the associator process cannot fail the job; what `took` adds
        # to the 0.5 s is that start, seconds at most even on a loaded machine.
        assert took < 20.0
        # What follows tests the worker and its new associator process, not the next job's own
        # time: in a fresh process on a loaded machine, kmeans++ on the paper batch has taken
        # longer than 0.5 s, so the next job gets a limit no load reaches.
        worker.settings = worker.settings.model_copy(update={"job_timeout_seconds": 600.0})
        assert worker.run_once()
        assert _job(sessions, following).state == "succeeded"
        assert worker.associator_process.pid not in (None, os.getpid())
    finally:
        worker.close()


def test_a_job_whose_associator_process_dies_is_retried(
    worker: Worker, sessions: sessionmaker[Session], enqueue: EnqueueJob
) -> None:
    """A child killed from outside (e.g. by the kernel for its memory) costs an attempt."""
    job_id = enqueue("test-sleeping", SLOW, max_attempts=2)
    runner = threading.Thread(target=worker.run_once)
    runner.start()
    _wait_until_running(sessions, job_id)
    child = worker.associator_process.pid
    assert child is not None
    os.kill(child, 9)
    runner.join(10)
    assert not runner.is_alive()
    job = _job(sessions, job_id)
    assert (job.state, job.attempts) == ("queued", 1)
    assert job.error is not None and "associator process died (exit code -9)" in job.error
