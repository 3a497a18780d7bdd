"""Liveness, readiness and metrics."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from fastapi.testclient import TestClient

from roadlink.api import create_app
from roadlink.queue.worker import Worker
from roadlink.settings import Settings
from tests.helpers import assert_problem


def test_healthz_and_readyz(client: TestClient) -> None:
    assert client.get("/healthz").json() == {"status": "ok"}
    ready = client.get("/readyz").json()
    assert ready["status"] == "ready" and ready["revision"]


def test_readyz_is_503_before_migrations(tmp_path: Path) -> None:
    settings = Settings(database_url=f"sqlite:///{tmp_path / 'fresh.db'}")
    with TestClient(create_app(settings)) as fresh:
        problem = assert_problem(fresh.get("/readyz"), 503)
    assert "roadlink migrate" in problem["detail"]


def test_metrics_count_requests_jobs_and_durations(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_csv: str
) -> None:
    for associator in ("kmeans", "kmeans++"):
        client.post(
            f"/v1/deployments/{deployment['id']}/batches",
            content=paper_csv,
            headers={"content-type": "text/csv"},
            params={"associator": associator},
        )
    assert worker.run_once()
    text = client.get("/metrics").text
    samples = {
        line.rsplit(" ", 1)[0]: float(line.rsplit(" ", 1)[1])
        for line in text.splitlines()
        if line and not line.startswith("#")
    }
    assert samples['roadlink_jobs{state="queued"}'] == 1
    assert samples['roadlink_jobs{state="succeeded"}'] == 1
    assert samples["roadlink_queue_depth"] == 1
    assert samples["roadlink_job_duration_seconds_count"] == 1
    assert samples['roadlink_job_duration_seconds_bucket{le="+Inf"}'] == 1
    assert samples["roadlink_job_duration_seconds_sum"] > 0
    key = (
        'roadlink_http_requests_total{method="POST",'
        'route="/v1/deployments/{deployment_id}/batches",status="201"}'
    )
    assert samples[key] == 2
