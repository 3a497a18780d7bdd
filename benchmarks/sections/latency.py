"""Latency: a paper-sized batch (100 detections) posted with `associate` (the default
associator) to a real `roadlink serve` on the embedded default (SQLite, one worker process per
core), until its result has been read with `GET /v1/jobs/{id}/result?wait=`.

Goals: p50 at most 50 ms, p99 at most 200 ms, and at most 20 ms of service overhead: the p50
minus the p50 of the same batches associated in process (`roadlink.association.associate`,
timed right after each sample). One client, one batch at a time, a short pause
between batches (so that each finds the workers idle, as a gateway posting every few seconds
does).
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import numpy as np
import orjson

from benchmarks.live_service import checked, create_deployment, json_batch, live_service
from benchmarks.report import Column, Sample, Section, Table
from roadlink.association import associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate

NAME = "latency"
GOAL_P50_SECONDS = 0.050
GOAL_P99_SECONDS = 0.200
# Issue 19: what the service adds to the association itself.
GOAL_OVERHEAD_SECONDS = 0.020
WAIT_SECONDS = 30


@dataclass(frozen=True)
class LatencyPlan:
    """How many batches to time, after how many untimed warm-up ones, and the pause between."""

    samples: int
    warmup: int = 5
    pause_seconds: float = 0.05


FULL = LatencyPlan(samples=300)
QUICK = LatencyPlan(samples=40, warmup=3)


def percentile(values: list[float], share: float) -> float:
    """The `share` quantile of `values` (linear interpolation, as numpy's default)."""
    return float(np.percentile(np.asarray(values, dtype=float), share * 100))


@dataclass(frozen=True)
class LatencyRuns:
    """Seconds per sample: through the service, and the in-process association of the same
    batch right after it."""

    service: list[float]
    library: list[float]


def measure_latency(plan: LatencyPlan, workers: int | None = None) -> LatencyRuns:
    """Seconds from posting each batch to having read its result, for `plan.samples` batches
    (seeds differ, so every batch is new data), each followed by the same batch associated in
    this process (`roadlink.association.associate`, the same associator and parameters)."""
    batches = [
        simulate(preset("large"), seed=seed).detections
        for seed in range(plan.warmup + plan.samples)
    ]
    runs = LatencyRuns([], [])
    with live_service(workers=workers) as service, service.client() as client:
        url = f"/v1/deployments/{create_deployment(client)}/batches"
        headers = {"content-type": "application/json"}
        for k, detections in enumerate(batches):
            body = orjson.dumps(
                json_batch(detections, associate={"associator": DEFAULT_ASSOCIATOR})
            )
            time.sleep(plan.pause_seconds)
            start = time.perf_counter()
            posted = checked(client.post(url, content=body, headers=headers)).json()
            job = posted["job"]["id"]
            checked(client.get(f"/v1/jobs/{job}/result", params={"wait": WAIT_SECONDS}))
            elapsed = time.perf_counter() - start
            start = time.perf_counter()
            associate(detections, DEFAULT_ASSOCIATOR, {})
            library = time.perf_counter() - start
            if k >= plan.warmup:
                runs.service.append(elapsed)
                runs.library.append(library)
    return runs


def run(quick: bool) -> Section:
    """The latency section (see the module docstring)."""
    plan = QUICK if quick else FULL
    runs = measure_latency(plan)
    timings = runs.service
    p50, p90, p99 = (percentile(timings, q) for q in (0.5, 0.9, 0.99))
    library_p50 = percentile(runs.library, 0.5)
    overhead = p50 - library_p50
    table = Table(
        "Post a 100-detection batch with `associate`, read its result",
        [
            Column("samples", "count"),
            Column("p50", "seconds"),
            Column("p90", "seconds"),
            Column("p99", "seconds"),
            Column("max", "seconds"),
            Column("in-process p50", "seconds"),
            Column("service overhead (p50 - in-process p50)", "seconds"),
            Column("goal p50 <= 50 ms"),
            Column("goal p99 <= 200 ms"),
            Column("goal overhead <= 20 ms"),
        ],
    )
    table.add(
        len(timings),
        p50,
        p90,
        p99,
        max(timings),
        library_p50,
        overhead,
        "met" if p50 <= GOAL_P50_SECONDS else "missed",
        "met" if p99 <= GOAL_P99_SECONDS else "missed",
        "met" if overhead <= GOAL_OVERHEAD_SECONDS else "missed",
    )
    differences = [s - lib for s, lib in zip(runs.service, runs.library, strict=True)]
    table.notes.append(
        f"- Each sample: POST the batch (JSON, `associate` = {DEFAULT_ASSOCIATOR}), then "
        f"`GET /v1/jobs/{{id}}/result?wait={WAIT_SECONDS}`; then the same batch through "
        "`roadlink.association.associate` in this process (in-process). One client, "
        f"{plan.pause_seconds * 1000:.0f} ms between samples, after {plan.warmup} untimed ones. "
        f"Median of the per-sample differences: {percentile(differences, 0.5) * 1000:.1f} ms."
    )
    return Section(
        NAME,
        "End-to-end latency of a paper-sized job on the embedded default (`roadlink serve`: "
        f"SQLite, synchronous={Settings().sqlite_synchronous}, one worker process per core at "
        f"worker niceness {Settings().worker_niceness}), "
        "over HTTP, beside the in-process association of the same batches.",
        tables=[table],
        settings={
            "samples": len(timings),
            "warmup": plan.warmup,
            "pause_seconds": plan.pause_seconds,
            "associator": DEFAULT_ASSOCIATOR,
            "timings": Sample.of(timings).to_dict(),
            "library_timings": Sample.of(runs.library).to_dict(),
            "overhead_seconds": overhead,
            "sqlite_synchronous": Settings().sqlite_synchronous,
            "worker_niceness": Settings().worker_niceness,
            "auth": "required (admin key), rate limit off",
        },
    )
