"""A real `roadlink serve` for the service sections: its own process, free loopback port, fresh
database, an admin API key; measured from outside over HTTP.

Authentication stays on (as in production): an admin key is made as `roadlink keys create
--scope admin` makes it (`create_api_key`, here in process: a `roadlink` subprocess would cost
seconds of imports per server), and sent on every request. The per-key rate limit is turned off
(`ROADLINK_RATE_LIMIT_PER_SECOND=0`), since one benchmark client sends far more than a gateway.
"""

from __future__ import annotations

import os
import socket
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx

from roadlink.association.detections import Detections
from roadlink.db.apikeys import create_api_key
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.models import ApiKeyScope
from roadlink.settings import Settings
from tests.helpers import detection_rows

READY_TIMEOUT_SECONDS = 90.0
REQUEST_TIMEOUT_SECONDS = 300.0


@dataclass(frozen=True)
class LiveService:
    """A running service: where it listens, the key to use, and its database."""

    base_url: str
    key: str
    database_url: str
    pid: int

    def client(self) -> httpx.Client:
        """An HTTP client for this service, sending the admin key."""
        return httpx.Client(
            base_url=self.base_url,
            headers={"Authorization": f"Bearer {self.key}"},
            timeout=REQUEST_TIMEOUT_SECONDS,
        )


def free_port() -> int:
    """A TCP port nothing listens on now, on 127.0.0.1."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _environment(database_url: str, extra: dict[str, str] | None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("ROADLINK_")}
    env.update(
        ROADLINK_DATABASE_URL=database_url,
        # The settings passed on from the benchmark's environment: the sections report them.
        ROADLINK_SQLITE_SYNCHRONOUS=Settings().sqlite_synchronous,
        ROADLINK_WORKER_NICENESS=str(Settings().worker_niceness),
        ROADLINK_LOG_LEVEL="warning",
        ROADLINK_RATE_LIMIT_PER_SECOND="0",
        **(extra or {}),
    )
    return env


def admin_key(database_url: str) -> str:
    """Migrate the database and create an admin API key in it; the key."""
    upgrade_to_head(database_url)
    engine = make_engine(database_url)
    try:
        with transaction(make_session_factory(engine)) as session:
            return create_api_key(session, scope=ApiKeyScope.ADMIN, name="bench").key
    finally:
        engine.dispose()


@contextmanager
def live_service(
    *,
    workers: int | None = None,
    database_url: str | None = None,
    environment: dict[str, str] | None = None,
) -> Iterator[LiveService]:
    """Start `roadlink serve` (workers: its --workers, None = the default, one per core) on a
    fresh SQLite file in a temporary directory, or on `database_url` (which must be empty or
    migrated); stop it (SIGTERM, then SIGKILL) afterwards."""
    with tempfile.TemporaryDirectory(prefix="roadlink-bench-") as directory:
        workdir = Path(directory)
        url = database_url or f"sqlite:///{workdir / 'roadlink.db'}"
        env = _environment(url, environment)
        key = admin_key(url)
        port = free_port()
        argv = ["serve", "--host", "127.0.0.1", "--port", str(port)]
        if workers is not None:
            argv += ["--workers", str(workers)]
        log = (workdir / "serve.log").open("w")
        process = subprocess.Popen(
            [sys.executable, "-m", "roadlink.cli", *argv],
            cwd=workdir,
            env=env,
            stdout=log,
            stderr=subprocess.STDOUT,
        )
        service = LiveService(f"http://127.0.0.1:{port}", key, url, process.pid)
        try:
            _wait_until_ready(service, process, workdir / "serve.log")
            yield service
        finally:
            process.terminate()
            try:
                process.wait(20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            log.close()


def _wait_until_ready(service: LiveService, process: subprocess.Popen[Any], log: Path) -> None:
    deadline = time.monotonic() + READY_TIMEOUT_SECONDS
    with httpx.Client(base_url=service.base_url, timeout=2.0) as client:
        while time.monotonic() < deadline:
            if process.poll() is not None:
                output = log.read_text()
                raise RuntimeError(f"roadlink serve exited ({process.returncode}): {output}")
            try:
                if client.get("/readyz").status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.1)
    raise RuntimeError(f"roadlink serve not ready after {READY_TIMEOUT_SECONDS} s")


def create_deployment(client: httpx.Client, name: str = "bench") -> str:
    """A new deployment's id (no declared sensors)."""
    response = client.post("/v1/deployments", json={"name": name})
    response.raise_for_status()
    return str(response.json()["id"])


def json_batch(detections: Detections, associate: dict[str, Any] | None = None) -> dict[str, Any]:
    """A JSON batch body (BatchCreate in openapi/openapi.json) holding `detections`."""
    body: dict[str, Any] = {"detections": detection_rows(detections)}
    if associate is not None:
        body["associate"] = associate
    return body


def checked(response: httpx.Response) -> httpx.Response:
    """The response, or an error naming what the service said."""
    if response.is_error:
        raise RuntimeError(
            f"{response.request.method} {response.request.url.path}: "
            f"{response.status_code} {response.text[:500]}"
        )
    return response
