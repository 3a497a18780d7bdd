"""Overhead: a 10,000-detection job through a real `roadlink serve`, end to end (post the batch
with `associate`, read the result with `?wait=`), divided by the in-process library call
(`roadlink.association.associate`) on the same detections with the same associator.

Goal: at most 1.5. The two are interleaved, repeat by repeat, so that both see the same load.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import orjson

from benchmarks.datasets import cached_dataset, load_detections, scaled_config, targets_for
from benchmarks.live_service import checked, create_deployment, json_batch, live_service
from benchmarks.report import Column, Sample, Section, Table
from roadlink.association import associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR

NAME = "overhead"
GOAL_RATIO = 1.5
WAIT_SECONDS = 600


@dataclass(frozen=True)
class OverheadPlan:
    """Detections per job and repeats."""

    detections: int
    repeats: int


FULL = OverheadPlan(detections=10_000, repeats=5)
QUICK = OverheadPlan(detections=10_000, repeats=3)


@dataclass(frozen=True)
class OverheadRuns:
    """Seconds per repeat: end to end, the job's own duration as the worker recorded it, and
    the in-process call."""

    service: list[float]
    job: list[float]
    library: list[float]


def measure_overhead(
    plan: OverheadPlan, associator: str = DEFAULT_ASSOCIATOR, workers: int | None = None
) -> OverheadRuns:
    """Service and library seconds per repeat, after one untimed warm-up of each (`workers`:
    the server's worker processes; None = its default, one per core)."""
    detections = load_detections(cached_dataset(scaled_config(targets_for(plan.detections))))
    body = orjson.dumps(json_batch(detections, associate={"associator": associator}))
    runs = OverheadRuns([], [], [])
    with live_service(workers=workers) as service, service.client() as client:
        url = f"/v1/deployments/{create_deployment(client)}/batches"
        headers = {"content-type": "application/json"}
        for k in range(plan.repeats + 1):
            start = time.perf_counter()
            job = checked(client.post(url, content=body, headers=headers)).json()["job"]["id"]
            checked(client.get(f"/v1/jobs/{job}/result", params={"wait": WAIT_SECONDS}))
            elapsed = time.perf_counter() - start
            duration = checked(client.get(f"/v1/jobs/{job}")).json()["duration_seconds"]
            start = time.perf_counter()
            associate(detections, associator, {})
            library = time.perf_counter() - start
            if k > 0:  # the first of each is a warm-up
                runs.service.append(elapsed)
                runs.job.append(float(duration))
                runs.library.append(library)
    return runs


def run(quick: bool) -> Section:
    """The overhead section (see the module docstring)."""
    plan = QUICK if quick else FULL
    runs = measure_overhead(plan)
    service, job, library = (Sample.of(r) for r in (runs.service, runs.job, runs.library))
    ratio = service.median / library.median
    table = Table(
        f"A {plan.detections:,}-detection job: service end to end / library call",
        [
            Column("associator"),
            Column("detections", "count"),
            Column("service end to end", "seconds"),
            Column("worker's job duration", "seconds"),
            Column("library call", "seconds"),
            Column("ratio"),
            Column("goal <= 1.5"),
        ],
    )
    table.add(
        DEFAULT_ASSOCIATOR,
        plan.detections,
        service,
        job,
        library,
        f"{ratio:.2f}",
        "met" if ratio <= GOAL_RATIO else "missed",
    )
    table.notes.append(
        "- End to end: POST the JSON batch with `associate`, then GET the result with `?wait=`. "
        "The worker's job duration is from its claim to its result being stored (loading the "
        "detections, the associator child process, storing the result). The ratio is of the "
        "medians."
    )
    return Section(
        NAME,
        "The service's cost on top of the association itself: a job end to end over HTTP "
        "(`roadlink serve`, SQLite), divided by `roadlink.association.associate` on the same "
        f"detections in this process. Median [min, max] of {plan.repeats} interleaved repeats.",
        tables=[table],
        settings={
            "detections": plan.detections,
            "repeats": plan.repeats,
            "associator": DEFAULT_ASSOCIATOR,
            "ratio": ratio,
            "goal_ratio": GOAL_RATIO,
            "auth": "required (admin key), rate limit off",
        },
    )
