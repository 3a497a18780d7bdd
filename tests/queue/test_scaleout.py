"""Scaled out to four worker processes on PostgreSQL, the queue finishes each job exactly once
while workers are killed and frozen (the worker alone: `test_worker`)."""

from __future__ import annotations

import multiprocessing
import os
import signal
import time
import uuid
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from sqlalchemy import func, select, text

from roadlink.db import repository
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.json_columns import BatchSelection
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.models import Job, JobResult
from roadlink.queue import enqueue_job
from roadlink.queue.transitions import NOTIFY_CHANNEL
from roadlink.queue.worker import run_worker_process
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.databases import create_postgres_database, drop_postgres_database, postgres_answers
from tests.queue import associators_for_tests

pytestmark = pytest.mark.usefixtures("test_associators")


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
