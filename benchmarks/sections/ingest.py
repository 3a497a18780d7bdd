"""Ingest: detections per second of a 100,000-detection batch posted to a real `roadlink serve`,
JSON and CSV, until the response says it is committed to the SQLite file, beside the limit
measured in the same run on the same machine.

The limit is what any service must at least do with that body: parse it (orjson, or the csv
module) and write the same rows with sqlite3 `executemany` in one transaction into the service's
own `detection` table (a fresh database migrated to the same schema: same indexes and foreign
keys, same PRAGMAs: WAL, synchronous=FULL), then commit. Goal: the service reaches at least 40%
of it.
"""

from __future__ import annotations

import csv
import io
import sqlite3
import tempfile
import time
import uuid
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import orjson

from benchmarks.datasets import cached_dataset, load_detections, scaled_config, targets_for
from benchmarks.live_service import checked, create_deployment, json_batch, live_service
from benchmarks.report import Column, Sample, Section, Table
from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.db.migrate import upgrade_to_head

NAME = "ingest"
GOAL_SHARE = 0.40


@dataclass(frozen=True)
class IngestPlan:
    """How many detections per batch and how many repeats of each measurement."""

    detections: int
    repeats: int


FULL = IngestPlan(detections=100_000, repeats=5)
QUICK = IngestPlan(detections=30_000, repeats=3)

INSERT = (
    "INSERT INTO detection (batch_id, deployment_id, row, position, velocity, timestamp, "
    "sensor_id, detection_id, target) VALUES (?, ?, ?, ?, ?, ?, ?, ?, ?)"
)


class LimitDatabase:
    """A fresh SQLite file at the service's schema, written with nothing but sqlite3."""

    def __init__(self, path: Path) -> None:
        upgrade_to_head(f"sqlite:///{path}")
        self.connection = sqlite3.connect(path, isolation_level=None)
        for pragma in ("journal_mode=WAL", "synchronous=FULL", "foreign_keys=ON"):
            self.connection.execute(f"PRAGMA {pragma}")
        # SQLAlchemy's Uuid type stores 32 hex digits in SQLite; the same here.
        self.deployment = uuid.uuid4().hex
        self.connection.execute(
            "INSERT INTO deployment (id, name, created_at) VALUES (?, 'limit', '2026-01-01')",
            (self.deployment,),
        )

    def store(self, rows: Callable[[str, str], list[tuple[Any, ...]]]) -> None:
        """One batch row and its detections in one transaction, committed."""
        batch = uuid.uuid4().hex
        connection = self.connection
        connection.execute("BEGIN")
        connection.execute(
            "INSERT INTO batch (id, deployment_id, n_detections, n_labelled, first_timestamp, "
            "last_timestamp, source, created_at) VALUES (?, ?, 0, 0, 0, 0, 'limit', '2026-01-01')",
            (batch, self.deployment),
        )
        connection.executemany(INSERT, rows(batch, self.deployment))
        connection.execute("COMMIT")

    def close(self) -> None:
        self.connection.close()


def json_rows(body: bytes) -> Callable[[str, str], list[tuple[Any, ...]]]:
    """The limit's parse of a JSON body, as the rows to insert."""

    def rows(batch: str, deployment: str) -> list[tuple[Any, ...]]:
        return [
            (
                batch,
                deployment,
                i,
                d["position"],
                d["velocity"],
                d["timestamp"],
                d.get("sensor_id"),
                d.get("detection_id"),
                d.get("target"),
            )
            for i, d in enumerate(orjson.loads(body)["detections"], start=1)
        ]

    return rows


def csv_rows(body: bytes) -> Callable[[str, str], list[tuple[Any, ...]]]:
    """The limit's parse of a CSV body (header: the detection CSV's column order), as the rows."""

    def rows(batch: str, deployment: str) -> list[tuple[Any, ...]]:
        reader = csv.reader(io.StringIO(body.decode()))
        next(reader)
        return [
            (batch, deployment, i, float(p), float(v), float(t), s, d, target or None)
            for i, (p, v, t, s, d, target) in enumerate(reader, start=1)
        ]

    return rows


def bodies(detections: Detections) -> dict[str, tuple[bytes, str]]:
    """The same detections as a JSON and as a CSV body, with their content types."""
    return {
        "json": (orjson.dumps(json_batch(detections)), "application/json"),
        "csv": (write_detections_csv(detections).encode(), "text/csv"),
    }


def measure_both(
    payloads: dict[str, tuple[bytes, str]], repeats: int, directory: Path
) -> tuple[dict[str, list[float]], dict[str, list[float]]]:
    """Seconds per repeat, of the service (sending each body until its 201) and of the limit
    (parsing it and inserting its rows in one committed transaction), interleaved so that both
    see the same load on a shared machine."""
    service_runs: dict[str, list[float]] = {kind: [] for kind in payloads}
    limit_runs: dict[str, list[float]] = {kind: [] for kind in payloads}
    limits = {kind: LimitDatabase(directory / f"limit-{kind}.db") for kind in payloads}
    parsers = {"json": json_rows, "csv": csv_rows}
    try:
        # No workers: nothing here runs jobs, and idle workers would only share the CPU.
        with live_service(workers=0) as service, service.client() as client:
            deployment = create_deployment(client)
            url = f"/v1/deployments/{deployment}/batches"
            for body, content_type in payloads.values():  # warm-up: imports, first-use caches
                checked(client.post(url, content=body, headers={"content-type": content_type}))
            for _ in range(repeats):
                for kind, (body, content_type) in payloads.items():
                    start = time.perf_counter()
                    response = client.post(
                        url, content=body, headers={"content-type": content_type}
                    )
                    service_runs[kind].append(time.perf_counter() - start)
                    checked(response)
                    start = time.perf_counter()
                    limits[kind].store(parsers[kind](body))
                    limit_runs[kind].append(time.perf_counter() - start)
    finally:
        for database in limits.values():
            database.close()
    return service_runs, limit_runs


def run(quick: bool) -> Section:
    """Service and limit, JSON and CSV (see the module docstring)."""
    plan = QUICK if quick else FULL
    return measure_ingest(plan)


def measure_ingest(plan: IngestPlan) -> Section:
    """The ingest section for `plan`."""
    config = scaled_config(targets_for(plan.detections))
    detections = load_detections(cached_dataset(config))
    payloads = bodies(detections)
    n = len(detections)
    with tempfile.TemporaryDirectory(prefix="roadlink-limit-") as directory:
        service_runs, limit_runs = measure_both(payloads, plan.repeats, Path(directory))
    table = Table(
        "Batch upload, end to end",
        [
            Column("format"),
            Column("detections", "count"),
            Column("body MiB", "text"),
            Column("service seconds", "seconds"),
            Column("service detections/s", "count"),
            Column("limit seconds", "seconds"),
            Column("limit detections/s", "count"),
            Column("service / limit", "share"),
            Column("goal >= 40%"),
        ],
    )
    ratios = {}
    for kind, (body, _) in payloads.items():
        service = Sample.of(service_runs[kind])
        limit = Sample.of(limit_runs[kind])
        ratio = limit.median / service.median
        ratios[kind] = ratio
        table.add(
            kind,
            n,
            f"{len(body) / 2**20:.1f}",
            service,
            n / service.median,
            limit,
            n / limit.median,
            ratio,
            "met" if ratio >= GOAL_SHARE else "missed",
        )
    table.notes.append(
        "- Rates are of the median seconds; the ratio is limit seconds / service seconds."
    )
    return Section(
        NAME,
        f"A {n:,}-detection batch POSTed to `roadlink serve --workers 0` (SQLite, WAL, "
        "synchronous=FULL) "
        "until its 201, beside the limit: the same body parsed with orjson (or csv) and its rows "
        "inserted with sqlite3 executemany into the same schema in one committed transaction. "
        f"Median [min, max] of {plan.repeats} repeats, service and limit interleaved, after one "
        "warm-up upload of each format (quick mode: 30,000 detections).",
        tables=[table],
        settings={
            "detections": n,
            "repeats": plan.repeats,
            "goal_share": GOAL_SHARE,
            "ratios": ratios,
            "auth": "required (admin key), rate limit off",
        },
    )
