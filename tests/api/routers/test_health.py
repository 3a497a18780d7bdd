"""Liveness, readiness and metrics."""

from __future__ import annotations

from pathlib import Path

from fastapi.testclient import TestClient

from roadlink.api import create_app
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


def test_metrics_are_served_without_a_key_in_prometheus_text_format(client: TestClient) -> None:
    # What they count: tests/api/test_prometheus.py.
    response = TestClient(client.app).get("/metrics")
    assert response.status_code == 200
    assert response.headers["content-type"].startswith("text/plain; version=")
    assert "roadlink_queue_depth 0.0" in response.text.splitlines()
