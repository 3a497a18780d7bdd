"""When the database fails under the service: every answer is a problem with an error id that the
log carries, a database that cannot take writes is a 503 with Retry-After (and /readyz says so),
and once the storage is back the service recovers by itself, without a restart."""

from __future__ import annotations

import logging
import shutil
import sqlite3
import subprocess
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient
from sqlalchemy.exc import OperationalError

from roadlink.association.csvio import write_detections_csv
from roadlink.db import repository
from roadlink.simulation import preset, simulate
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env


def _answers_with_a_logged_problem(response: httpx.Response, status: int, caplog: Any) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/problem+json"
    problem = dict(response.json())
    assert problem["error_id"] and problem["error_id"] in problem["detail"]
    logged = [r for r in caplog.records if problem["error_id"] in r.getMessage()]
    assert logged and logged[0].exc_info is not None  # the traceback, under the same id
    return problem


@pytest.mark.parametrize(
    ("fault", "status"),
    [
        (OperationalError("INSERT", {}, sqlite3.OperationalError("database or disk is full")), 503),
        (OperationalError("INSERT", {}, sqlite3.OperationalError("database is locked")), 503),
        (RuntimeError("a bug, with a /secret/path in its message"), 500),
    ],
)
def test_an_unexpected_error_is_a_problem_with_an_id_the_log_carries(
    client: TestClient,
    deployment: dict[str, Any],
    paper_csv: str,
    monkeypatch: pytest.MonkeyPatch,
    caplog: pytest.LogCaptureFixture,
    fault: Exception,
    status: int,
) -> None:
    def failing(*_args: object, **_kwargs: object) -> None:
        raise fault

    monkeypatch.setattr(repository, "insert_batch", failing)
    caplog.set_level(logging.ERROR, logger="roadlink")
    response = client.post(
        f"/v1/deployments/{deployment['id']}/batches",
        content=paper_csv,
        headers={"content-type": "text/csv"},
    )
    _answers_with_a_logged_problem(response, status, caplog)
    assert "secret" not in response.text and "sqlite" not in response.text.lower()
    if status == 503:
        assert response.headers["Retry-After"] == "5"


def _chattr(flag: str, *paths: Path) -> None:
    subprocess.run(["chattr", flag, *map(str, paths)], check=True, capture_output=True)


@pytest.fixture
def immutable(tmp_path: Path) -> Iterator[list[Path]]:
    """Paths to make immutable (chattr +i: not even root may write them), made writable after."""
    probe = tmp_path / "probe"
    probe.touch()
    if shutil.which("chattr") is None:
        pytest.skip("no chattr (e2fsprogs): cannot make the database read-only for root")
    try:
        _chattr("+i", probe)
    except subprocess.CalledProcessError as exc:
        pytest.skip(f"chattr +i is not supported here: {exc.stderr.decode().strip()}")
    _chattr("-i", probe)
    paths: list[Path] = []
    yield paths
    existing = [p for p in paths if p.exists()]
    if existing:
        _chattr("-i", *existing)


def _post(url: str, key: str, body: str) -> httpx.Response:
    return httpx.post(
        url,
        content=body,
        headers={"Authorization": f"Bearer {key}", "content-type": "text/csv"},
        timeout=120,
    )


@pytest.mark.slow
def test_a_read_only_database_is_a_503_and_the_service_recovers_when_it_is_writable_again(
    tmp_path: Path, immutable: list[Path]
) -> None:
    server = LiveServer(tmp_path, sqlite_env(tmp_path), free_port())
    server.start(workers=0)
    try:
        key = roadlink("keys", "create", "--scope", "admin", env=server.env, cwd=tmp_path).strip()
        auth = {"Authorization": f"Bearer {key}"}
        deployment = httpx.post(f"{server.url}/v1/deployments", json={"name": "ro"}, headers=auth)
        url = f"{server.url}/v1/deployments/{deployment.json()['id']}/batches"
        bodies = [
            write_detections_csv(simulate(preset("large"), seed=s).detections) for s in (1, 2, 3)
        ]
        assert _post(url, key, bodies[0]).status_code == 201

        database = tmp_path / "roadlink.db"
        # The directory, the database and its write-ahead log. (Not the shared-memory index,
        # which SQLite maps into memory: refusing it under a running process is a crash, not a
        # read-only disk.)
        immutable.extend([tmp_path, database, tmp_path / "roadlink.db-wal"])
        _chattr("+i", *immutable)
        for _ in range(3):
            refused = _post(url, key, bodies[1])
            assert refused.status_code == 503, refused.text
            assert refused.headers["content-type"] == "application/problem+json"
            assert refused.headers["Retry-After"] == "5" and refused.json()["error_id"]
        not_ready = httpx.get(f"{server.url}/readyz", timeout=60)
        assert not_ready.status_code == 503 and "does not take writes" in not_ready.text

        _chattr("-i", *immutable)
        deadline = time.monotonic() + 60
        while (answer := _post(url, key, bodies[1])).status_code != 201:
            assert answer.status_code == 503, answer.text
            assert time.monotonic() < deadline, "the service did not recover"
            time.sleep(0.5)
        assert _post(url, key, bodies[2]).status_code == 201
        assert httpx.get(f"{server.url}/readyz", timeout=60).status_code == 200
        with sqlite3.connect(database) as connection:
            assert connection.execute("SELECT count(*) FROM batch").fetchone() == (3,)
    finally:
        server.stop()
