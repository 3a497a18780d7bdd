"""Latency: a paper-sized batch (100 detections) posted with `associate` (the default
associator) to a real `roadlink serve` on the embedded default (SQLite, one worker process per
core), until its result has been read with `GET /v1/jobs/{id}/result?wait=`.

Goal: p50 at most 50 ms, p99 at most 200 ms. One client, one batch at a time, a short pause
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
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.simulation import preset, simulate

NAME = "latency"
GOAL_P50_SECONDS = 0.050
GOAL_P99_SECONDS = 0.200
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


def measure_latency(plan: LatencyPlan, workers: int | None = None) -> list[float]:
    """Seconds from posting each batch to having read its result, for `plan.samples` batches
    (seeds differ, so every batch is new data)."""
    batches = [
        orjson.dumps(
            json_batch(
                simulate(preset("large"), seed=seed).detections,
                associate={"associator": DEFAULT_ASSOCIATOR},
            )
        )
        for seed in range(plan.warmup + plan.samples)
    ]
    timings = []
    with live_service(workers=workers) as service, service.client() as client:
        url = f"/v1/deployments/{create_deployment(client)}/batches"
        headers = {"content-type": "application/json"}
        for k, body in enumerate(batches):
            time.sleep(plan.pause_seconds)
            start = time.perf_counter()
            posted = checked(client.post(url, content=body, headers=headers)).json()
            job = posted["job"]["id"]
            checked(client.get(f"/v1/jobs/{job}/result", params={"wait": WAIT_SECONDS}))
            if k >= plan.warmup:
                timings.append(time.perf_counter() - start)
    return timings


def run(quick: bool) -> Section:
    """The latency section (see the module docstring)."""
    plan = QUICK if quick else FULL
    timings = measure_latency(plan)
    p50, p90, p99 = (percentile(timings, q) for q in (0.5, 0.9, 0.99))
    table = Table(
        "Post a 100-detection batch with `associate`, read its result",
        [
            Column("samples", "count"),
            Column("p50", "seconds"),
            Column("p90", "seconds"),
            Column("p99", "seconds"),
            Column("max", "seconds"),
            Column("goal p50 <= 50 ms"),
            Column("goal p99 <= 200 ms"),
        ],
    )
    table.add(
        len(timings),
        p50,
        p90,
        p99,
        max(timings),
        "met" if p50 <= GOAL_P50_SECONDS else "missed",
        "met" if p99 <= GOAL_P99_SECONDS else "missed",
    )
    table.notes.append(
        f"- Each sample: POST the batch (JSON, `associate` = {DEFAULT_ASSOCIATOR}), then "
        f"`GET /v1/jobs/{{id}}/result?wait={WAIT_SECONDS}`; one client, "
        f"{plan.pause_seconds * 1000:.0f} ms between samples, after {plan.warmup} untimed ones."
    )
    return Section(
        NAME,
        "End-to-end latency of a paper-sized job on the embedded default (`roadlink serve`: "
        "SQLite, one worker process per core), over HTTP.",
        tables=[table],
        settings={
            "samples": len(timings),
            "warmup": plan.warmup,
            "pause_seconds": plan.pause_seconds,
            "associator": DEFAULT_ASSOCIATOR,
            "timings": Sample.of(timings).to_dict(),
            "auth": "required (admin key), rate limit off",
        },
    )
