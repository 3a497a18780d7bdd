"""The worker: runs the core on a claimed job and stores exactly what the core returns; retries
crashes, not user errors; stops when its job is cancelled; hands its job back when stopping;
kills a job past its time limit and goes on to the next; and, scaled out to four processes on
PostgreSQL, finishes each job exactly once while workers are killed and frozen."""

from __future__ import annotations

import multiprocessing
import os
import signal
import threading
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import orjson
import pytest
from sqlalchemy import Engine, func, select, text
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association import associate
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.json_columns import BatchSelection
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.models import Job, JobResult
from roadlink.queue import enqueue_job
from roadlink.queue.transitions import NOTIFY_CHANNEL
from roadlink.queue.worker import Worker, run_worker_process
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.databases import create_postgres_database, drop_postgres_database, postgres_answers
from tests.helpers import EnqueueJob
from tests.queue import associators_for_tests

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
    from roadlink.db.engine import transaction
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


# Scaling out: four worker processes on one PostgreSQL database: 502 jobs, each succeeds exactly
# once, while one worker is killed with SIGKILL and another frozen with SIGSTOP in the middle of
# a job.
#
# Delivery is at least once, so a job may *run* more than once: the frozen worker's associator
# finishes its run while another worker, which rescued the expired lease, runs the job again.
# What must never happen twice is the *finish*: the guarded transition to `succeeded` (and the
# result stored with it). The test records both independently of the code under test: every run
# an associator completes (a line in a log file, written by the test associator), and every state
# transition of every job (a trigger on the job table of this test's own database).

WORKERS = 4
JOBS = 500
VICTIM_SECONDS = 3.0  # long enough to be caught mid-run, short enough to re-run quickly

RECORD_TRANSITIONS = """
CREATE TABLE test_transition (
    -- Rows come back in no guaranteed order without ORDER BY (concurrent inserts may land on
    -- different pages): the sequence records the order the transitions happened in.
    seq bigserial PRIMARY KEY,
    job_id uuid NOT NULL,
    old_state text NOT NULL,
    new_state text NOT NULL,
    owner text,
    attempts integer NOT NULL
);
CREATE FUNCTION test_record_transition() RETURNS trigger LANGUAGE plpgsql AS $$
BEGIN
    INSERT INTO test_transition (job_id, old_state, new_state, owner, attempts)
    VALUES (NEW.id, OLD.state, NEW.state, COALESCE(NEW.lease_owner, OLD.lease_owner), NEW.attempts);
    RETURN NEW;
END $$;
CREATE TRIGGER test_job_transition AFTER UPDATE ON job FOR EACH ROW
    WHEN (OLD.state IS DISTINCT FROM NEW.state) EXECUTE FUNCTION test_record_transition();
"""


def _work(settings: Settings) -> None:
    """A worker process that also knows the test associators."""
    associators_for_tests.register()
    run_worker_process(settings)


@pytest.fixture
def scaleout_database() -> Iterator[str]:
    if not postgres_answers():
        pytest.skip("PostgreSQL tests skipped: nothing answers on 127.0.0.1:5432")
    url = create_postgres_database()
    try:
        upgrade_to_head(url)
        engine = make_engine(url)
        with engine.begin() as connection:
            connection.exec_driver_sql(RECORD_TRANSITIONS)
        engine.dispose()
        yield url
    finally:
        drop_postgres_database(url)


def _wait_until(condition: Any, timeout: float, what: str) -> Any:
    deadline = time.monotonic() + timeout
    while not (value := condition()):
        assert time.monotonic() < deadline, f"timed out waiting for {what}"
        time.sleep(0.05)
    return value


def _worker_pid(lease_owner: str) -> int:
    return int(lease_owner.split(":")[-2])  # host:pid:nonce


@pytest.mark.slow
@pytest.mark.postgres
def test_each_job_succeeds_exactly_once_across_killed_and_frozen_workers(
    scaleout_database: str, tmp_path: Path
) -> None:
    settings = Settings(
        database_url=scaleout_database,
        lease_seconds=1.5,
        heartbeat_seconds=0.25,
        poll_seconds=0.2,
        max_attempts=3,
        retry_backoff_seconds=0.0,
        job_timeout_seconds=30.0,
        log_level="warning",
    )
    runs_log = tmp_path / "runs.log"
    engine = make_engine(scaleout_database)
    sessions = make_session_factory(engine)
    with transaction(sessions) as session:
        deployment = repository.create_deployment(session, name="road", sensors=None)
        batch = repository.insert_batch(
            session,
            deployment_id=deployment.id,
            detections=simulate(preset("small"), seed=3).detections,
            source="simulation",
        )

    def enqueue(tags: list[str], seconds: float) -> list[uuid.UUID]:
        with transaction(sessions) as session:
            return [
                enqueue_job(
                    session,
                    deployment_id=deployment.id,
                    selection=BatchSelection((batch.id,)),
                    associator="test-sleeping",
                    params={"seconds": seconds, "log": str(runs_log), "tag": tag},
                    max_attempts=settings.max_attempts,
                ).id
                for tag in tags
            ]

    spawn = multiprocessing.get_context("spawn")
    workers = [spawn.Process(target=_work, args=(settings,)) for _ in range(WORKERS)]
    for process in workers:
        process.start()
    frozen_pid: int | None = None
    try:

        def listening_workers() -> bool:
            # A worker LISTENs once it is idle with its associator process started.
            with sessions() as session:
                listeners = session.scalar(
                    text(
                        "SELECT count(*) FROM pg_stat_activity "
                        "WHERE datname = current_database() AND query = :listen"
                    ),
                    {"listen": f"LISTEN {NOTIFY_CHANNEL}"},
                )
            return listeners == WORKERS

        # Each worker is a spawned interpreter that imports roadlink and starts its associator
        # process: cold starts that a loaded two-core machine has stretched past a minute.
        _wait_until(listening_workers, 180, "every worker to be ready")
        # Two slow jobs, each taken by its own worker: one worker is killed, one frozen.
        killed_job, frozen_job = enqueue(["killed", "frozen"], VICTIM_SECONDS)

        def owners() -> dict[uuid.UUID, str] | None:
            # Progress reached the database: each job is in its worker's associator process.
            with sessions() as session:
                rows = session.execute(
                    select(Job.id, Job.lease_owner).where(Job.state == "running", Job.progress > 0)
                ).all()
            found = {job_id: owner for job_id, owner in rows if owner}
            return found if len(found) == 2 else None

        running = _wait_until(owners, VICTIM_SECONDS, "both slow jobs to be under way")
        killed_pid, frozen_pid = _worker_pid(running[killed_job]), _worker_pid(running[frozen_job])
        os.kill(killed_pid, signal.SIGKILL)
        os.kill(frozen_pid, signal.SIGSTOP)
        fast_jobs = enqueue([f"job-{k}" for k in range(JOBS)], 0.0)

        def frozen_job_done_elsewhere() -> bool:
            with sessions() as session:
                job = repository.get_job(session, job_id=frozen_job)
                return job is not None and job.state == "succeeded"

        _wait_until(frozen_job_done_elsewhere, 30, "the frozen worker's job to be rescued")
        # Thawed: its associator finished the job meanwhile; its lease is gone.
        os.kill(frozen_pid, signal.SIGCONT)
        frozen_pid = None

        all_jobs = [killed_job, frozen_job, *fast_jobs]

        def all_finished() -> bool:
            with sessions() as session:
                unfinished = session.scalar(
                    select(func.count()).where(Job.state.in_(["queued", "running"]))
                )
            return unfinished == 0

        _wait_until(all_finished, 45, "every job to finish")
        alive = [p.pid for p in workers if p.is_alive()]
    finally:
        if frozen_pid is not None:
            os.kill(frozen_pid, signal.SIGCONT)
        for process in workers:
            if process.is_alive():
                process.terminate()
        for process in workers:
            process.join(10)

    # None lost: every job succeeded and has its result.
    with sessions() as session:
        states = Counter(session.scalars(select(Job.state)).all())
        results = session.scalar(select(func.count()).select_from(JobResult))
        attempts = dict(session.execute(select(Job.id, Job.attempts)).all())
        transitions = session.execute(
            text("SELECT job_id, old_state, new_state, owner FROM test_transition ORDER BY seq")
        ).all()
    engine.dispose()
    assert states == {"succeeded": len(all_jobs)}
    assert results == len(all_jobs)

    # None finished twice: one transition to succeeded per job, though some ran twice.
    succeeded_by = {}
    for job_id, old_state, new_state, owner in transitions:
        if new_state == "succeeded":
            assert job_id not in succeeded_by, f"job {job_id} succeeded twice"
            assert old_state == "running"
            succeeded_by[job_id] = owner
    assert set(succeeded_by) == set(all_jobs)
    runs = Counter(line.split()[0] for line in runs_log.read_text().splitlines())
    assert all(runs[f"job-{k}"] >= 1 for k in range(JOBS))

    # The killed worker's job: its lease expired, it was requeued and another worker ran it.
    assert attempts[killed_job] == 2
    assert _worker_pid(succeeded_by[killed_job]) != killed_pid
    killed_history = [(o, n) for j, o, n, _ in transitions if j == killed_job]
    assert killed_history == [
        ("queued", "running"),
        ("running", "queued"),
        ("queued", "running"),
        ("running", "succeeded"),
    ]
    assert runs["killed"] == 1  # the killed worker's associator died with it

    # The frozen worker's job ran to the end twice, and was finished once, by the rescuer; the
    # frozen worker, thawed, could not finish it again, and went on working.
    assert runs["frozen"] == 2
    assert attempts[frozen_job] == 2
    frozen_owner = running[frozen_job]
    assert succeeded_by[frozen_job] != frozen_owner
    assert _worker_pid(frozen_owner) in alive
    assert killed_pid not in alive
    assert len(alive) == WORKERS - 1
