"""Throughput: paper-sized jobs per second through a real `roadlink serve` with 1 and 2 worker
processes, on SQLite (the embedded default) and on PostgreSQL when it answers on 127.0.0.1:5432.

A paper-sized batch (the `large` preset: 10 targets x 10 sensors = 100 detections) is posted
once; then N jobs over it (default associator) are posted with `POST /v1/jobs`, one after
another, and their results read with `?wait=`; the rate is N divided by the time from the first
post to the last result. Each round follows a warm-up of two jobs per worker.
`benchmarks/scaleout.py` measures the same queue without HTTP (and wake-up latency).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import orjson

from benchmarks.live_service import checked, create_deployment, json_batch, live_service
from benchmarks.report import Column, Sample, Section, Table
from benchmarks.scaleout import fresh_database, postgres_answers
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.simulation import preset, simulate

NAME = "throughput"
WORKER_COUNTS = (1, 2)
QUICK_WORKER_COUNTS = (1,)  # each server start and warm-up costs seconds; --quick has two minutes
WAIT_SECONDS = 300


@dataclass(frozen=True)
class ThroughputPlan:
    """Jobs per round and rounds per (backend, worker count)."""

    jobs: int
    rounds: int


FULL = ThroughputPlan(jobs=100, rounds=3)
QUICK = ThroughputPlan(jobs=10, rounds=1)


def measure_throughput(database_url: str | None, workers: int, plan: ThroughputPlan) -> list[float]:
    """Jobs per second of each round, on a `roadlink serve --workers N` over `database_url`
    (None: a fresh SQLite file)."""
    body = orjson.dumps(json_batch(simulate(preset("large"), seed=7).detections))
    rates = []
    with (
        live_service(workers=workers, database_url=database_url) as service,
        service.client() as client,
    ):
        url = f"/v1/deployments/{create_deployment(client)}/batches"
        headers = {"content-type": "application/json"}
        batch = checked(client.post(url, content=body, headers=headers)).json()["id"]

        def round_of(jobs: int) -> float:
            start = time.perf_counter()
            ids = [
                checked(
                    client.post(
                        "/v1/jobs", json={"batch_id": batch, "associator": DEFAULT_ASSOCIATOR}
                    )
                ).json()["id"]
                for _ in range(jobs)
            ]
            for job in ids:
                checked(client.get(f"/v1/jobs/{job}/result", params={"wait": WAIT_SECONDS}))
            return jobs / (time.perf_counter() - start)

        round_of(2 * workers)
        rates = [round_of(plan.jobs) for _ in range(plan.rounds)]
    return rates


def backends(quick: bool) -> list[str]:
    """SQLite, and PostgreSQL when a server answers (not in quick mode, which also runs one
    worker count only: each server start costs seconds)."""
    return ["sqlite", "postgresql"] if postgres_answers() and not quick else ["sqlite"]


def run(quick: bool) -> Section:
    """The throughput section (see the module docstring)."""
    plan = QUICK if quick else FULL
    table = Table(
        "Paper-sized jobs per second, over HTTP",
        [Column("database"), Column("worker processes", "count"), Column("jobs/s", "count")],
    )
    rates: dict[str, dict[int, list[float]]] = {}
    for backend in backends(quick):
        for workers in QUICK_WORKER_COUNTS if quick else WORKER_COUNTS:
            if backend == "sqlite":
                runs = measure_throughput(None, workers, plan)
            else:
                with fresh_database("postgresql") as url:
                    runs = measure_throughput(url, workers, plan)
            rates.setdefault(backend, {})[workers] = runs
            table.add(backend, workers, Sample.of(runs))
    table.notes.append(
        f"- {plan.jobs} jobs per round ({DEFAULT_ASSOCIATOR}, 100 detections each), "
        f"median [min, max] of {plan.rounds} round(s); jobs/s shown with no decimals."
    )
    return Section(
        NAME,
        "Paper-sized jobs through `roadlink serve --workers N`: posted with `POST /v1/jobs`, "
        "results read with `?wait=`, from the first post to the last result.",
        tables=[table],
        settings={
            "jobs_per_round": plan.jobs,
            "rounds": plan.rounds,
            "associator": DEFAULT_ASSOCIATOR,
            "rates": rates,
            "auth": "required (admin key), rate limit off",
        },
    )
