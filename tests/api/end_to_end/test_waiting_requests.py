"""Requests that wait (`?wait=` on a result) hold no database connection: many of them at once,
more than the connection pool holds, leave the API answering everyone else."""

from __future__ import annotations

import threading
import time
from pathlib import Path

import httpx
import pytest

from roadlink.association.csvio import write_detections_csv
from roadlink.simulation import preset, simulate
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env

pytestmark = pytest.mark.slow

# SQLAlchemy's default pool: 5 connections and 10 more on demand. Twice that many wait at once.
WAITERS = 32
WAIT_SECONDS = 12


def test_many_waiting_result_requests_leave_the_api_answering(tmp_path: Path) -> None:
    env = sqlite_env(tmp_path, ROADLINK_RATE_LIMIT_PER_SECOND="0")
    server = LiveServer(tmp_path, env, free_port())
    server.start(workers=0)  # no workers: the job stays unfinished for the whole wait
    try:
        key = roadlink("keys", "create", "--scope", "admin", env=env, cwd=tmp_path).strip()
        auth = {"Authorization": f"Bearer {key}"}
        with httpx.Client(base_url=server.url, headers=auth, timeout=WAIT_SECONDS + 60) as http:
            deployment = http.post("/v1/deployments", json={"name": "waits"}).json()["id"]
            csv_text = write_detections_csv(simulate(preset("large"), seed=1).detections)
            batch = http.post(
                f"/v1/deployments/{deployment}/batches",
                content=csv_text,
                headers={"content-type": "text/csv"},
                params={"associator": "kmeans"},
            ).json()
            job = batch["job"]["id"]

            answers: list[int] = []
            lock = threading.Lock()

            def wait_for_result() -> None:
                with httpx.Client(
                    base_url=server.url, headers=auth, timeout=WAIT_SECONDS + 60
                ) as c:
                    status = c.get(
                        f"/v1/jobs/{job}/result", params={"wait": WAIT_SECONDS}
                    ).status_code
                with lock:
                    answers.append(status)

            waiters = [threading.Thread(target=wait_for_result) for _ in range(WAITERS)]
            for waiter in waiters:
                waiter.start()
            time.sleep(1.0)  # not synchronisation: the checks below hold however many wait yet
            # While they wait: requests that need the database, one after another.
            for k in range(5):
                began = time.monotonic()
                assert http.get(f"/v1/jobs/{job}").status_code == 200
                posted = http.post(
                    f"/v1/deployments/{deployment}/batches",
                    content=write_detections_csv(simulate(preset("large"), seed=10 + k).detections),
                    headers={"content-type": "text/csv"},
                )
                assert posted.status_code == 201, posted.text
                assert http.get("/readyz").status_code == 200
                # Generous for a loaded machine; a pool taken by the waiters made these wait for
                # the pool's 30 s timeout and fail.
                assert time.monotonic() - began < WAIT_SECONDS / 2
            with lock:
                assert len(answers) < WAITERS  # at least some still waited meanwhile
            for waiter in waiters:
                waiter.join()
        assert answers == [409] * WAITERS  # the job never finished: unfinished, not an error
    finally:
        server.stop()
