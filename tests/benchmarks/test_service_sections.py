"""The service sections' machinery on tiny sizes: a real server starts and stops, each measure
returns one timing per repeat, and the limit writes what the service writes.

Never asserts speed: benchmarks/ reports timings.
"""

import sqlite3

import httpx
import orjson
import pytest

from benchmarks import datasets
from benchmarks.live_service import checked, create_deployment, live_service
from benchmarks.report import Section
from benchmarks.sections import ingest, latency, overhead, throughput
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate
from tests.databases import create_postgres_database, drop_postgres_database, require_postgres


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Simulated data sets go to a temporary cache, not the real one."""
    monkeypatch.setattr(datasets, "CACHE", tmp_path / "cache")


def _stored(rows: list[tuple[object, ...]], detections: Detections) -> None:
    """Each of two stores wrote every row of the body, in order, with its row number."""
    first = rows[: len(detections)]
    assert len(rows) == 2 * len(detections)
    assert [r[0] for r in first] == list(range(1, len(detections) + 1))
    assert [r[1:4] for r in first] == list(
        zip(detections.position, detections.velocity, detections.timestamp, strict=True)
    )
    assert [r[6] for r in first] == list(detections.target)


@pytest.mark.parametrize("kind", ["json", "csv"])
def test_the_plain_limit_stores_the_rows_the_body_holds(tmp_path, kind):
    detections = simulate(preset("small"), seed=3).detections
    body, _ = ingest.bodies(detections)[kind]
    database = ingest.PlainSqlite(tmp_path / "plain.db", "full")
    database.store(ingest.PARSERS[kind](body))
    database.store(ingest.PARSERS[kind](body))
    database.close()
    with sqlite3.connect(tmp_path / "plain.db") as connection:
        rows = connection.execute(
            f"SELECT {ingest.PLAIN_COLUMNS} FROM plain_detection ORDER BY rowid"
        ).fetchall()
        indexes = connection.execute("SELECT count(*) FROM sqlite_master WHERE type = 'index'")
        assert indexes.fetchone() == (0,)
        assert connection.execute("PRAGMA journal_mode").fetchone()[0] == "wal"
    _stored(rows, detections)


def test_the_bodies_with_features_carry_lane_length_and_class():
    detections = simulate(preset("small"), seed=3).detections
    payloads = ingest.bodies(detections)
    assert sorted(payloads) == ["csv", "csv + features", "json", "json + features"]
    header = payloads["csv + features"][0].split(b"\n", 1)[0].decode()
    assert header.endswith("lane,length,vehicle_class")
    assert payloads["csv"][0].split(b"\n", 1)[0].decode().split(",")[-1] == "target"
    rows = orjson.loads(payloads["json + features"][0])["detections"]
    assert len(rows) == len(detections)
    assert all(row["length"] > 0 for row in rows if row["length"] is not None)
    assert {"lane", "length", "vehicle_class"} <= set(rows[0])
    assert "lane" not in orjson.loads(payloads["json"][0])["detections"][0]


def test_the_plain_limit_copies_into_postgresql():
    require_postgres()
    detections = simulate(preset("small"), seed=3).detections
    body, _ = ingest.bodies(detections)["csv"]
    url = create_postgres_database()
    try:
        database = ingest.PlainPostgres(url)
        database.store(ingest.csv_rows(body))
        database.store(ingest.csv_rows(body))
        rows = database.connection.execute(
            f"SELECT {ingest.PLAIN_COLUMNS} FROM plain_detection"
        ).fetchall()
        database.close()
    finally:
        drop_postgres_database(url)
    _stored(rows, detections)


def test_percentiles_interpolate_like_numpy():
    assert latency.percentile([1.0, 2.0, 3.0, 4.0], 0.5) == 2.5
    assert latency.percentile([5.0], 0.99) == 5.0


@pytest.mark.slow
def test_a_live_service_needs_its_key_and_stops_afterwards():
    with live_service(workers=0) as service:
        with service.client() as client:
            deployment = create_deployment(client)
            assert checked(client.get(f"/v1/deployments/{deployment}")).json()["id"]
        assert httpx.get(f"{service.base_url}/v1/deployments").status_code == 401
    with pytest.raises(httpx.TransportError):
        httpx.get(f"{service.base_url}/healthz", timeout=2.0)


@pytest.mark.slow
def test_ingest_times_service_and_limit_once_per_repeat_and_format():
    plan = ingest.IngestPlan(detections=200, repeats=2, databases=("sqlite",))
    section = ingest.measure_ingest(plan)
    table, features = section.tables
    assert [row[:2] for row in table.rows] == [["sqlite", "json"], ["sqlite", "csv"]]
    assert all(len(row[4].runs) == 2 and len(row[6].runs) == 2 for row in table.rows)
    assert set(section.settings["ratios"]) == {"sqlite/json", "sqlite/csv"}
    # The batches with lane, length and class, each beside the same batch without them.
    assert [row[:2] for row in features.rows] == [["sqlite", "json"], ["sqlite", "csv"]]
    assert all(len(row[3].runs) == 2 and len(row[4].runs) == 2 for row in features.rows)
    assert set(section.settings["feature_ratios"]) == {"sqlite/json", "sqlite/csv"}


@pytest.mark.slow
def test_latency_times_each_sample_after_the_warm_up_beside_the_library(monkeypatch):
    # The section waits 30 s for a result; on a loaded host a fresh server's first job took
    # longer. This test is about the machinery, never the speed: wait as long as the server
    # lets a request wait (ROADLINK_MAX_WAIT_SECONDS, 60 s by default).
    monkeypatch.setattr(latency, "WAIT_SECONDS", 600)
    plan = latency.LatencyPlan(samples=3, warmup=1, pause_seconds=0)
    runs = latency.measure_latency(plan, workers=1)
    assert len(runs.service) == len(runs.library) == 3
    assert all(t > 0 for t in runs.service + runs.library)


@pytest.mark.slow
def test_overhead_times_service_job_and_library_per_repeat():
    runs = overhead.measure_overhead(overhead.OverheadPlan(detections=200, repeats=2), workers=1)
    assert len(runs.service) == len(runs.job) == len(runs.library) == 2
    assert all(j <= s for j, s in zip(runs.job, runs.service, strict=True))


@pytest.mark.slow
def test_throughput_reports_a_rate_per_round():
    rates = throughput.measure_throughput(None, 1, throughput.ThroughputPlan(jobs=2, rounds=2))
    assert len(rates) == 2 and all(r > 0 for r in rates)


def test_sections_round_trip_through_their_json():
    section = Section("x", "y", settings={"ratios": {"json": 0.5}})
    assert Section.from_dict(section.to_dict()).settings == {"ratios": {"json": 0.5}}
