"""Against a real server: `roadlink serve` started by the test on a free loopback port, with a
real SQLite file and a worker process; driven by plain HTTP and by a client generated from the
committed OpenAPI document."""

from __future__ import annotations

import http.client
import importlib
import json
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import httpx
import pytest

from roadlink.association import associate
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.simulation import preset, simulate
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parents[3]
MAX_BODY_BYTES = 100_000


class Running(NamedTuple):
    url: str
    key: str  # an admin API key, made with `roadlink keys create` as the docs say

    @property
    def headers(self) -> dict[str, str]:
        return {"Authorization": f"Bearer {self.key}"}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Running]:
    """`roadlink serve --workers 1` on a fresh SQLite file, and an admin key for it."""
    directory = tmp_path_factory.mktemp("live")
    live = LiveServer(
        directory, sqlite_env(directory, ROADLINK_MAX_BODY_BYTES=str(MAX_BODY_BYTES)), free_port()
    )
    key = roadlink("keys", "create", "--scope", "admin", env=live.env, cwd=directory).strip()
    live.start(workers=1)
    try:
        yield Running(live.url, key)
    finally:
        live.stop()  # SIGINT, as Ctrl-C: the API and its workers stop


def test_a_paper_sized_batch_over_http(server: Running) -> None:
    detections = simulate(preset("large"), seed=21).detections
    text = write_detections_csv(detections)
    # The result request waits as long as the server lets it (60 s): a fresh server's first job
    # waited in the queue for more than 20 s on a host at load 10.
    with httpx.Client(base_url=server.url, headers=server.headers, timeout=90) as http:
        deployment = http.post("/v1/deployments", json={"name": "live"}).json()
        batch = http.post(
            f"/v1/deployments/{deployment['id']}/batches",
            content=text,
            headers={"content-type": "text/csv"},
            params={"associator": "kmeans++"},
        )
        assert batch.status_code == 201, batch.text
        result = http.get(f"/v1/jobs/{batch.json()['job']['id']}/result", params={"wait": 60})
        assert result.status_code == 200, result.text
        expected = associate(read_detections_csv(text), "kmeans++").to_dict()
        assert result.json() == json.loads(json.dumps(expected))

        too_big = http.post(
            f"/v1/deployments/{deployment['id']}/batches",
            content=b"x" * (MAX_BODY_BYTES + 1),
            headers={"content-type": "text/csv"},
        )
        assert too_big.status_code == 413
        assert str(MAX_BODY_BYTES) in too_big.json()["detail"]
        metrics = http.get("/metrics").text
        assert 'roadlink_jobs{state="succeeded"} 1.0' in metrics


def test_a_generated_client_drives_the_server(server: Running, tmp_path: Path) -> None:
    config = tmp_path / "config.yaml"
    config.write_text("package_name_override: roadlink_client\npost_hooks: []\n")
    generated = subprocess.run(
        [
            str(Path(sys.executable).parent / "openapi-python-client"),
            "generate",
            "--path",
            str(REPO / "openapi" / "openapi.json"),
            "--meta",
            "none",
            "--output-path",
            str(tmp_path / "roadlink_client"),
            "--config",
            str(config),
        ],
        capture_output=True,
        text=True,
        timeout=120,
    )
    assert generated.returncode == 0, generated.stdout + generated.stderr
    sys.path.insert(0, str(tmp_path))
    try:
        client_module = importlib.import_module("roadlink_client")
        from roadlink_client.api.batches import batches_create
        from roadlink_client.api.deployments import deployments_create
        from roadlink_client.api.jobs import jobs_create, jobs_get, jobs_get_result
        from roadlink_client.models import (
            AssociateRequest,
            BatchCreate,
            DeploymentCreate,
            DetectionIn,
            JobCreate,
        )

        # The spec declares the bearer scheme, so the generated client has AuthenticatedClient.
        client = client_module.AuthenticatedClient(
            base_url=server.url, token=server.key, timeout=httpx.Timeout(30)
        )
        deployment = deployments_create.sync(
            client=client, body=DeploymentCreate(name="generated client")
        )
        detections = simulate(preset("medium"), seed=8).detections
        rows = [
            DetectionIn(
                position=float(detections.position[i]),
                velocity=float(detections.velocity[i]),
                timestamp=float(detections.timestamp[i]),
                sensor_id=str(detections.sensor_id[i]),
                detection_id=str(detections.detection_id[i]),
                target=str(detections.target[i]),
            )
            for i in range(len(detections))
        ]
        batch = batches_create.sync(deployment.id, client=client, body=BatchCreate(detections=rows))
        assert batch.n_detections == len(detections)
        job = jobs_create.sync(
            client=client,
            body=JobCreate(
                batch_id=batch.id, associator="kmeans", params=AssociateRequest().params
            ),
        )
        result = jobs_get_result.sync(job.id, client=client, wait=20.0)
        assert result.n_detections == len(detections)
        assert result.metrics.accuracy == pytest.approx(
            associate(detections, "kmeans").metrics.accuracy  # type: ignore[union-attr]
        )
        assert jobs_get.sync(job.id, client=client).state.value == "succeeded"
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m.startswith("roadlink_client")]:
            del sys.modules[name]


def test_an_idle_connection_outlives_a_client_pools_expiry(server: Running) -> None:
    # httpx drops an idle pooled connection after 5 s, which was also uvicorn's keep-alive: a
    # request sent as the server closed its side was lost (`RemoteProtocolError`, once in a
    # 180 s soak). The server now waits ROADLINK_KEEP_ALIVE_SECONDS (75 s): idle for longer than
    # a pool's expiry (the behaviour under test, hence the wait), the connection still answers.
    host, port = server.url.removeprefix("http://").split(":")
    connection = http.client.HTTPConnection(host, int(port), timeout=30)
    try:
        connection.request("GET", "/healthz")
        assert connection.getresponse().read() and connection.sock is not None
        first = connection.sock
        time.sleep(6.0)
        connection.request("GET", "/healthz")
        response = connection.getresponse()
        assert response.status == 200 and connection.sock is first
        response.read()
    finally:
        connection.close()
