"""Scale-out benchmark: paper-sized jobs per second with 1, 2 and 4 worker processes, on
PostgreSQL and on SQLite, and how soon an idle worker starts a job after its enqueue commits.

    .venv/bin/python benchmarks/scaleout.py [--quick]

Prints a table and writes benchmarks/results/scaleout.json. `run(quick)` returns the rows.

Throughput: a paper-sized batch (the `large` preset: 10 targets x 10 sensors = 100 detections,
labelled) is stored once; N jobs over it with the default associator are enqueued in one
transaction while the workers idle (warmed up by one job each); the rate is N divided by the
time from that commit to the last job's finish. Median of 3 rounds on the same workers.

Wake-up latency: one idle worker; a job is enqueued, and the time from just before its commit
to its claim (`started_at`, stamped by the database on PostgreSQL) is recorded; 50 jobs, each
enqueued once the previous one finished and the worker idles again.

PostgreSQL rows need the server on 127.0.0.1:5432 (each run creates and drops its own database).
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import multiprocessing.process
import os
import statistics
import sys
import tempfile
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

from sqlalchemy import func, select
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.db import repository
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.json_columns import BatchSelection
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.models import Job, JobState
from roadlink.queue import enqueue_job
from roadlink.queue.worker import run_worker_process
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.databases import create_postgres_database, drop_postgres_database, postgres_answers

RESULTS = Path(__file__).resolve().parent / "results" / "scaleout.json"
WORKER_COUNTS = (1, 2, 4)
ROUNDS = 3


@contextmanager
def fresh_database(backend: str) -> Iterator[str]:
    """A migrated, empty database of `backend`, removed afterwards; its URL."""
    if backend == "sqlite":
        with tempfile.TemporaryDirectory() as directory:
            url = f"sqlite:///{directory}/roadlink.db"
            upgrade_to_head(url)
            yield url
        return
    url = create_postgres_database()
    try:
        upgrade_to_head(url)
        yield url
    finally:
        drop_postgres_database(url)


@contextmanager
def worker_processes(settings: Settings, count: int) -> Iterator[None]:
    """`count` worker processes, as `roadlink worker --workers N` runs them."""
    spawn = multiprocessing.get_context("spawn")
    processes: list[multiprocessing.process.BaseProcess] = [
        spawn.Process(target=run_worker_process, args=(settings,)) for _ in range(count)
    ]
    for process in processes:
        process.start()
    try:
        yield
    finally:
        for process in processes:
            process.terminate()
        for process in processes:
            process.join(10)


class Queue:
    """The benchmark's side of the queue: one stored paper-sized batch, jobs over it."""

    def __init__(self, database_url: str) -> None:
        self.engine = make_engine(database_url)
        self.sessions: sessionmaker[Session] = make_session_factory(self.engine)
        with transaction(self.sessions) as session:
            deployment = repository.create_deployment(session, name="bench", sensors=None)
            batch = repository.insert_batch(
                session,
                deployment_id=deployment.id,
                detections=simulate(preset("large"), seed=7).detections,
                source="simulation",
            )
        self.deployment_id, self.batch_id = deployment.id, batch.id

    def enqueue(self, count: int) -> tuple[list[uuid.UUID], float]:
        """Enqueue `count` jobs in one transaction; their ids and the wall time of the commit."""
        with self.sessions() as session:
            session.begin()
            ids = [
                enqueue_job(
                    session,
                    deployment_id=self.deployment_id,
                    selection=BatchSelection((self.batch_id,)),
                    associator=DEFAULT_ASSOCIATOR,
                    params={},
                    max_attempts=1,
                ).id
                for _ in range(count)
            ]
            committing = time.time()  # just before: the latency measured is an upper bound
            session.commit()
        return ids, committing

    def wait_until_finished(self, ids: list[uuid.UUID], timeout: float = 600.0) -> None:
        """Until none of `ids` is queued or running; raises if any failed."""
        deadline = time.monotonic() + timeout
        while True:
            with self.sessions() as session:
                states = dict(
                    session.execute(
                        select(Job.state, func.count()).where(Job.id.in_(ids)).group_by(Job.state)
                    ).all()
                )
            if not states.get(JobState.QUEUED) and not states.get(JobState.RUNNING):
                if set(states) != {JobState.SUCCEEDED}:
                    raise RuntimeError(f"jobs did not all succeed: {states}")
                return
            if time.monotonic() > deadline:
                raise TimeoutError(f"jobs unfinished after {timeout} s: {states}")
            time.sleep(0.02)

    def times(self, ids: list[uuid.UUID], column: Any) -> list[datetime]:
        """A timestamp column of the jobs, in the order of `ids`."""
        with self.sessions() as session:
            found: dict[uuid.UUID, datetime] = dict(
                session.execute(select(Job.id, column).where(Job.id.in_(ids))).all()
            )
        return [found[i] for i in ids]

    def close(self) -> None:
        self.engine.dispose()


def _settings(database_url: str) -> Settings:
    return Settings(database_url=database_url, log_level="warning")


def measure_throughput(backend: str, workers: int, jobs: int, rounds: int) -> dict[str, Any]:
    """Jobs per second of `workers` worker processes, median of `rounds` rounds."""
    with fresh_database(backend) as url:
        queue = Queue(url)
        try:
            with worker_processes(_settings(url), workers):
                warmup, _ = queue.enqueue(2 * workers)
                queue.wait_until_finished(warmup, timeout=120)
                rates = []
                for _ in range(rounds):
                    ids, committed = queue.enqueue(jobs)
                    queue.wait_until_finished(ids)
                    last = max(queue.times(ids, Job.finished_at)).timestamp()
                    rates.append(jobs / (last - committed))
        finally:
            queue.close()
    return {
        "measure": "throughput",
        "backend": backend,
        "workers": workers,
        "jobs_per_round": jobs,
        "rounds": [round(r, 1) for r in rates],
        "jobs_per_second": round(statistics.median(rates), 1),
    }


def measure_wakeup(backend: str, jobs: int) -> dict[str, Any]:
    """Milliseconds from an enqueue's commit to an idle worker's claim: median and p95."""
    with fresh_database(backend) as url:
        queue = Queue(url)
        try:
            with worker_processes(_settings(url), 1):
                warmup, _ = queue.enqueue(1)
                queue.wait_until_finished(warmup, timeout=120)
                latencies = []
                for _ in range(jobs):
                    time.sleep(0.1)  # the worker is idle, waiting for a notification
                    ids, committed = queue.enqueue(1)
                    queue.wait_until_finished(ids)
                    started = queue.times(ids, Job.started_at)[0].timestamp()
                    latencies.append((started - committed) * 1000)
        finally:
            queue.close()
    latencies.sort()
    return {
        "measure": "wakeup_latency",
        "backend": backend,
        "workers": 1,
        "jobs": jobs,
        "median_ms": round(statistics.median(latencies), 1),
        "p95_ms": round(latencies[max(0, round(0.95 * len(latencies)) - 1)], 1),
        "max_ms": round(latencies[-1], 1),
    }


def run(quick: bool) -> list[dict[str, Any]]:
    """Every measurement, as rows: throughput per backend and worker count, then wake-up
    latency per backend. `quick` runs fewer jobs and one round (for a smoke run)."""
    backends = ["postgresql", "sqlite"] if postgres_answers() else ["sqlite"]
    jobs, rounds, wakeups = (40, 1, 10) if quick else (200, ROUNDS, 50)
    rows = [
        measure_throughput(backend, workers, jobs, rounds)
        for backend in backends
        for workers in WORKER_COUNTS
    ]
    rows += [measure_wakeup(backend, wakeups) for backend in backends]
    return rows


def table(rows: list[dict[str, Any]]) -> str:
    """The throughput rows as a Markdown table (jobs/s per backend and worker count), and the
    wake-up latencies."""
    throughput = [r for r in rows if r["measure"] == "throughput"]
    backends = list(dict.fromkeys(r["backend"] for r in throughput))
    lines = [
        "| worker processes | " + " | ".join(f"{b} jobs/s" for b in backends) + " |",
        "|---:|" + "---:|" * len(backends),
    ]
    for workers in WORKER_COUNTS:
        cells = [
            next(
                (
                    str(r["jobs_per_second"])
                    for r in throughput
                    if r["backend"] == b and r["workers"] == workers
                ),
                "-",
            )
            for b in backends
        ]
        lines.append(f"| {workers} | " + " | ".join(cells) + " |")
    lines.append("")
    lines.append("| wake-up (enqueue commit to claim) | median ms | p95 ms | max ms |")
    lines.append("|---|---:|---:|---:|")
    for r in rows:
        if r["measure"] == "wakeup_latency":
            cells = [str(r[k]) for k in ("median_ms", "p95_ms", "max_ms")]
            lines.append(f"| {r['backend']}, idle worker | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--quick", action="store_true", help="fewer jobs, one round")
    args = parser.parse_args()
    load_before = os.getloadavg()
    rows = run(args.quick)
    load_after = os.getloadavg()
    print(table(rows))
    machine = {
        "cores": os.cpu_count(),
        "load_average_before": [round(x, 2) for x in load_before],
        "load_average_after": [round(x, 2) for x in load_after],
        "python": sys.version.split()[0],
        "measured_at": datetime.now(UTC).isoformat(timespec="seconds"),
        "quick": args.quick,
    }
    before, after = machine["load_average_before"], machine["load_average_after"]
    print(f"\nload average (1, 5, 15 min) before {before}, after {after}")
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(json.dumps({"machine": machine, "rows": rows}, indent=2) + "\n")
    print(f"wrote {RESULTS}")


if __name__ == "__main__":
    main()
