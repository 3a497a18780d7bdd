"""`GET /v1/jobs/{id}/result?wait=` is woken by the job's finish: on PostgreSQL by the NOTIFY
of the finishing transaction, on SQLite by the worker in this process; polling is the fallback."""

from __future__ import annotations

import threading
import time
from typing import Any

import pytest
from fastapi.testclient import TestClient

from roadlink.association.associators import ASSOCIATORS
from roadlink.queue.worker import Worker
from roadlink.services import waiting
from tests.helpers import post_csv_batch
from tests.queue.associators_for_tests import SleepingAssociator

# With polling this slow, only a notification can end the wait before the job's 60 s timeout.
NO_POLLING_SECONDS = 60.0


@pytest.fixture
def notifications_only(monkeypatch: pytest.MonkeyPatch) -> None:
    for name in ("WAIT_FIRST_POLL_SECONDS", "WAIT_MAX_POLL_SECONDS", "WAIT_LISTENING_POLL_SECONDS"):
        monkeypatch.setattr(waiting, name, NO_POLLING_SECONDS)
    monkeypatch.setitem(ASSOCIATORS, SleepingAssociator.name, SleepingAssociator)


def _post(client: TestClient, deployment: dict[str, Any], paper_csv: str, **params: str) -> Any:
    return post_csv_batch(client, deployment["id"], paper_csv, **params)["job"]["id"]


def test_a_waiting_request_is_woken_when_its_job_succeeds(
    notifications_only: None,
    client: TestClient,
    running_worker: Worker,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    job_id = _post(
        client, deployment, paper_csv, associator="test-sleeping", params='{"seconds": 0.5}'
    )
    began = time.monotonic()
    result = client.get(f"/v1/jobs/{job_id}/result", params={"wait": 10})
    assert result.status_code == 200, result.text
    assert result.json()["n_detections"] == 100
    # Started before the job finished (it takes 0.5 s) and ended long before the next poll.
    assert time.monotonic() - began < NO_POLLING_SECONDS / 4


def test_a_waiting_request_is_woken_when_its_job_is_cancelled(
    notifications_only: None, client: TestClient, deployment: dict[str, Any], paper_csv: str
) -> None:
    job_id = _post(client, deployment, paper_csv, associator="kmeans++")  # no worker: queued
    cancel = threading.Timer(0.3, lambda: client.post(f"/v1/jobs/{job_id}/cancel"))
    cancel.start()
    began = time.monotonic()
    result = client.get(f"/v1/jobs/{job_id}/result", params={"wait": 10})
    cancel.join()
    assert result.status_code == 409 and "cancelled" in result.json()["detail"]
    assert time.monotonic() - began < NO_POLLING_SECONDS / 4
