"""Ingest: detections per second of a 100,000-detection batch posted to a real `roadlink serve`,
JSON and CSV, until the response says it is committed, on SQLite and (when it answers) on
PostgreSQL, beside the plain limit measured in the same run on the same machine.

The plain limit is what any service must at least do with that body: parse it (orjson, or the
csv module) and write the same rows in one committed transaction into a plain table holding just
the detection's columns and its row number, with no key, no secondary index and no foreign key.
On SQLite with sqlite3 `executemany` and the service's PRAGMAs (WAL, its `synchronous`); on
PostgreSQL with psycopg 3's `COPY ... FROM STDIN`. Goal: the service reaches at least 40% of it.

The same batch with the three detector features (lane, length, vehicle class) is posted in the
same loop, right before or after the batch without them (the order alternating repeat by
repeat): the median of each repeat's with / without, goal at most 1.15 (issue 17). Beside it the
floor of that ratio, what no service can avoid with the larger body: the library's parse of it
(msgspec's typed decode, polars' `read_csv`, as the fast paths call them), timed in this
process, and its receive (the same body POSTed as text/plain, which the route refuses with a
415 once it has read it), each against the body without features, in the same loop.
"""

from __future__ import annotations

import csv
import io
import sqlite3
import statistics
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import orjson
import polars as pl
import psycopg
from sqlalchemy import make_url

from benchmarks.datasets import cached_dataset, load_detections, scaled_config, targets_for
from benchmarks.live_service import checked, create_deployment, json_batch, live_service
from benchmarks.report import Column, Sample, Section, Table
from benchmarks.scaleout import fresh_database, postgres_answers
from roadlink.api.json_detections import decode_rows
from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.settings import Settings
from tests.helpers import with_features

NAME = "ingest"
GOAL_SHARE = 0.40
GOAL_FEATURES = 1.15
FEATURED = " + features"  # the suffix of a payload's kind that carries lane, length and class


@dataclass(frozen=True)
class IngestPlan:
    """How many detections per batch, how many repeats of each measurement, on which databases."""

    detections: int
    repeats: int
    databases: tuple[str, ...] = ("sqlite", "postgresql")


FULL = IngestPlan(detections=100_000, repeats=7)
QUICK = IngestPlan(detections=30_000, repeats=3, databases=("sqlite",))

# The plain table: the detection's columns and its row number, nothing else.
PLAIN_COLUMNS = "row, position, velocity, timestamp, sensor_id, detection_id, target"
PLAIN_TABLE = (
    "CREATE TABLE plain_detection (row INTEGER, position DOUBLE PRECISION, "
    "velocity DOUBLE PRECISION, timestamp DOUBLE PRECISION, sensor_id TEXT, "
    "detection_id TEXT, target TEXT)"
)

Rows = list[tuple[Any, ...]]


class PlainDatabase(Protocol):
    """Where the plain limit writes: one committed transaction per `store`."""

    def store(self, rows: Rows) -> None: ...

    def close(self) -> None: ...


class PlainSqlite:
    """A SQLite file holding the plain table, with the service's PRAGMAs, written with sqlite3."""

    def __init__(self, path: Path, synchronous: str) -> None:
        self.connection = sqlite3.connect(path, isolation_level=None)
        for pragma in ("journal_mode=WAL", f"synchronous={synchronous}"):
            self.connection.execute(f"PRAGMA {pragma}")
        self.connection.execute(PLAIN_TABLE)

    def store(self, rows: Rows) -> None:
        connection = self.connection
        connection.execute("BEGIN")
        connection.executemany(
            f"INSERT INTO plain_detection ({PLAIN_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?)", rows
        )
        connection.execute("COMMIT")

    def close(self) -> None:
        self.connection.close()


class PlainPostgres:
    """The plain table in a PostgreSQL database, written with psycopg 3's COPY."""

    def __init__(self, database_url: str) -> None:
        url = make_url(database_url).set(drivername="postgresql")
        self.connection = psycopg.connect(url.render_as_string(hide_password=False))
        with self.connection.transaction():
            self.connection.execute(PLAIN_TABLE)

    def store(self, rows: Rows) -> None:
        statement = f"COPY plain_detection ({PLAIN_COLUMNS}) FROM STDIN"
        with (
            self.connection.transaction(),
            self.connection.cursor() as cursor,
            cursor.copy(statement) as copy,
        ):
            for row in rows:
                copy.write_row(row)

    def close(self) -> None:
        self.connection.close()


def json_rows(body: bytes) -> Rows:
    """The limit's parse of a JSON body, as the rows to write."""
    return [
        (
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


def csv_rows(body: bytes) -> Rows:
    """The limit's parse of a CSV body (header: the detection CSV's column order), as the rows."""
    reader = csv.reader(io.StringIO(body.decode()))
    next(reader)
    return [
        (i, float(p), float(v), float(t), s, d, target or None)
        for i, (p, v, t, s, d, target) in enumerate(reader, start=1)
    ]


PARSERS: dict[str, Callable[[bytes], Rows]] = {"json": json_rows, "csv": csv_rows}


def bodies(detections: Detections) -> dict[str, tuple[bytes, str]]:
    """The same detections as a JSON and as a CSV body, with their content types, each also
    with lane, length and vehicle class (`tests.helpers.with_features`)."""
    featured = with_features(detections)
    return {
        "json": (orjson.dumps(json_batch(detections)), "application/json"),
        "csv": (write_detections_csv(detections).encode(), "text/csv"),
        "json" + FEATURED: (orjson.dumps(json_batch(featured)), "application/json"),
        "csv" + FEATURED: (write_detections_csv(featured).encode(), "text/csv"),
    }


@contextmanager
def databases(backend: str, directory: Path) -> Iterator[tuple[str, PlainDatabase]]:
    """A fresh database for the service (its URL) and the plain limit's database beside it."""
    with fresh_database(backend) as url:
        plain: PlainDatabase
        if backend == "sqlite":
            plain = PlainSqlite(directory / "plain.db", Settings().sqlite_synchronous)
        else:
            plain = PlainPostgres(url)
        try:
            yield url, plain
        finally:
            plain.close()


def library_parse(kind: str, body: bytes) -> object:
    """The parsing library's own read of a body as the service's fast paths call it: msgspec's
    typed decode into rows (`decode_rows`), or polars' (numbers typed, the rest text, no
    quoting)."""
    if kind.startswith("json"):
        return decode_rows(body)
    header = body[: body.index(b"\n")].decode().split(",")
    numbers = ("position", "velocity", "timestamp", "lane", "length")
    schema = {name: pl.Float64 if name in numbers else pl.String for name in header}
    return pl.read_csv(body, has_header=False, skip_rows=1, schema=schema, quote_char=None)


@dataclass
class Runs:
    """Seconds per repeat: the service's (each body until its 201), the plain limit's (the
    bodies without features), and, for the floor, each body's receive (POSTed as text/plain,
    refused once read) and its library parse."""

    service: dict[str, list[float]]
    limit: dict[str, list[float]]
    receive: dict[str, list[float]]
    parse: dict[str, list[float]]


def measure_both(
    payloads: dict[str, tuple[bytes, str]], repeats: int, backend: str, directory: Path
) -> Runs:
    """The service and the limit, interleaved so that both see the same load on a shared
    machine; each body with features right before or after the same body without (the order
    alternating), with the floor's receive and parse beside."""
    runs = Runs(
        service={kind: [] for kind in payloads},
        limit={kind: [] for kind in payloads if kind in PARSERS},
        receive={kind: [] for kind in payloads},
        parse={kind: [] for kind in payloads},
    )
    service_runs, limit_runs = runs.service, runs.limit
    # No workers: nothing here runs jobs, and idle workers would only share the CPU.
    with (
        databases(backend, directory) as (url, plain),
        live_service(workers=0, database_url=url) as service,
        service.client() as client,
    ):
        deployment = create_deployment(client)
        url = f"/v1/deployments/{deployment}/batches"
        for body, content_type in payloads.values():  # warm-up: imports, first-use caches
            checked(client.post(url, content=body, headers={"content-type": content_type}))
        for repeat in range(repeats):
            for kind in PARSERS:
                pair = (kind, kind + FEATURED)
                for each in pair if repeat % 2 == 0 else pair[::-1]:
                    body, content_type = payloads[each]
                    start = time.perf_counter()
                    response = client.post(
                        url, content=body, headers={"content-type": content_type}
                    )
                    service_runs[each].append(time.perf_counter() - start)
                    checked(response)
                for each in pair:
                    body = payloads[each][0]
                    start = time.perf_counter()
                    refused = client.post(url, content=body, headers={"content-type": "text/plain"})
                    runs.receive[each].append(time.perf_counter() - start)
                    assert refused.status_code == 415, refused.status_code
                    start = time.perf_counter()
                    library_parse(each, body)
                    runs.parse[each].append(time.perf_counter() - start)
                start = time.perf_counter()
                plain.store(PARSERS[kind](payloads[kind][0]))
                limit_runs[kind].append(time.perf_counter() - start)
    return runs


def run(quick: bool) -> Section:
    """Service and limit, JSON and CSV, SQLite and PostgreSQL (see the module docstring)."""
    plan = QUICK if quick else FULL
    return measure_ingest(plan)


def measure_ingest(plan: IngestPlan) -> Section:
    """The ingest section for `plan` (PostgreSQL only when it answers)."""
    config = scaled_config(targets_for(plan.detections))
    detections = load_detections(cached_dataset(config))
    payloads = bodies(detections)
    n = len(detections)
    backends = [b for b in plan.databases if b == "sqlite" or postgres_answers()]
    table = Table(
        "Batch upload, end to end, beside the plain limit",
        [
            Column("database"),
            Column("format"),
            Column("detections", "count"),
            Column("body MiB", "text"),
            Column("service seconds", "seconds"),
            Column("service detections/s", "count"),
            Column("plain limit seconds", "seconds"),
            Column("plain limit detections/s", "count"),
            Column("service / plain limit", "share"),
            Column("goal >= 40%"),
        ],
    )
    features = Table(
        "The same batch with lane, length and class, beside it without them",
        [
            Column("database"),
            Column("format"),
            Column("body MiB", "text"),
            Column("service seconds", "seconds"),
            Column("without features", "seconds"),
            Column("with / without", "text"),
            Column("goal <= 1.15"),
            Column("parse + receive, larger body", "seconds"),
            Column("floor", "text"),
        ],
    )
    ratios: dict[str, float] = {}
    feature_ratios: dict[str, float] = {}
    floors: dict[str, float] = {}
    for backend in backends:
        with tempfile.TemporaryDirectory(prefix="roadlink-limit-") as scratch:
            runs = measure_both(payloads, plan.repeats, backend, Path(scratch))
        service_runs, limit_runs = runs.service, runs.limit
        for kind in limit_runs:
            body = payloads[kind + FEATURED][0]
            featured = Sample.of(service_runs[kind + FEATURED])
            plain_kind = Sample.of(service_runs[kind])
            # Each repeat's pair was posted one right after the other: their ratio, median.
            slower = statistics.median(
                a / b for a, b in zip(featured.runs, plain_kind.runs, strict=True)
            )
            feature_ratios[f"{backend}/{kind}"] = slower
            # What the larger body costs any service: parsing it and receiving it, more.
            extra = Sample.of(
                [
                    (p1 + r1) - (p0 + r0)
                    for p1, r1, p0, r0 in zip(
                        runs.parse[kind + FEATURED],
                        runs.receive[kind + FEATURED],
                        runs.parse[kind],
                        runs.receive[kind],
                        strict=True,
                    )
                ]
            )
            floor = 1 + extra.median / plain_kind.median
            floors[f"{backend}/{kind}"] = floor
            features.add(
                backend,
                kind,
                f"{len(body) / 2**20:.1f}",
                featured,
                plain_kind,
                f"{slower:.2f}",
                "met" if slower <= GOAL_FEATURES else "missed",
                extra,
                f"{floor:.2f}",
            )
        for kind in limit_runs:
            body = payloads[kind][0]
            service = Sample.of(service_runs[kind])
            limit = Sample.of(limit_runs[kind])
            ratio = limit.median / service.median
            ratios[f"{backend}/{kind}"] = ratio
            table.add(
                backend,
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
    features.notes.append(
        "- with / without: the median of each repeat's ratio (the two posted one right after "
        "the other). parse + receive: the library's parse (msgspec's typed decode; polars, as "
        "the fast paths read) and the receive (POSTed as text/plain, refused once read) of the "
        "body with features, less those of the body without; floor = 1 + that / the service's "
        "median without features."
    )
    table.notes.append(
        "- Rates are of the median seconds; the ratio is plain limit seconds / service seconds."
    )
    return Section(
        NAME,
        f"A {n:,}-detection batch POSTed to `roadlink serve --workers 0` until its 201, beside "
        "the plain limit: the same body parsed with orjson (or csv) and its rows written in one "
        "committed transaction into a plain table of the detection's columns (no key, no index): "
        f"sqlite3 executemany with the service's PRAGMAs (WAL, synchronous="
        f"{Settings().sqlite_synchronous}), psycopg 3 COPY on PostgreSQL. Median [min, max] of "
        f"{plan.repeats} repeats, service and limit interleaved, after one warm-up upload of "
        "each format (quick mode: 30,000 detections, SQLite only).",
        tables=[table, features],
        settings={
            "detections": n,
            "repeats": plan.repeats,
            "databases": backends,
            "goal_share": GOAL_SHARE,
            "goal_features": GOAL_FEATURES,
            "feature_ratios": feature_ratios,
            "feature_floors": floors,
            "ratios": ratios,
            "sqlite_synchronous": Settings().sqlite_synchronous,
            "auth": "required (admin key), rate limit off",
        },
    )
