"""The service sections' machinery on tiny sizes: a real server starts and stops, each measure
returns one timing per repeat, and the limit writes what the service writes.

Never asserts speed: benchmarks/ reports timings.
"""

import sqlite3

import httpx
import pytest

from benchmarks import datasets
from benchmarks.live_service import checked, create_deployment, live_service
from benchmarks.report import Section
from benchmarks.sections import ingest, latency, overhead, throughput
from roadlink.simulation import preset, simulate


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    """Simulated data sets go to a temporary cache, not the real one."""
    monkeypatch.setattr(datasets, "CACHE", tmp_path / "cache")


@pytest.mark.parametrize("kind", ["json", "csv"])
def test_the_limit_stores_the_rows_the_body_holds(tmp_path, kind):
    detections = simulate(preset("small"), seed=3).detections
    body, _ = ingest.bodies(detections)[kind]
    database = ingest.LimitDatabase(tmp_path / "limit.db")
    parse = ingest.json_rows if kind == "json" else ingest.csv_rows
    database.store(parse(body))
    database.store(parse(body))
    database.close()
    with sqlite3.connect(tmp_path / "limit.db") as connection:
        rows = connection.execute(
            "SELECT position, velocity, timestamp, sensor_id, detection_id, target "
            "FROM detection ORDER BY id"
        ).fetchall()
        mode = connection.execute("PRAGMA journal_mode").fetchone()[0]
    assert mode == "wal"
    first = rows[: len(detections)]
    assert len(rows) == 2 * len(detections)
    assert [r[:3] for r in first] == list(
        zip(detections.position, detections.velocity, detections.timestamp, strict=True)
    )
    assert [r[5] for r in first] == list(detections.target)


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
    section = ingest.measure_ingest(ingest.IngestPlan(detections=200, repeats=2))
    (table,) = section.tables
    assert [row[0] for row in table.rows] == ["json", "csv"]
    assert all(len(row[3].runs) == 2 and len(row[5].runs) == 2 for row in table.rows)
    assert set(section.settings["ratios"]) == {"json", "csv"}


@pytest.mark.slow
def test_latency_times_each_sample_after_the_warm_up():
    plan = latency.LatencyPlan(samples=3, warmup=1, pause_seconds=0)
    timings = latency.measure_latency(plan, workers=1)
    assert len(timings) == 3 and all(t > 0 for t in timings)


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
