"""Deleting a batch or a deployment through the API: admin only (tests/security/test_auth.py),
409 while a queued or running job reads the data, the detections and the jobs that read them
gone, and a line in the audit log; on SQLite and PostgreSQL."""

from __future__ import annotations

import logging
import uuid
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from roadlink.db.apikeys import key_prefix
from roadlink.queue.worker import Worker
from tests.helpers import assert_problem, post_csv_batch, row_counts


def run_all(worker: Worker) -> None:
    while worker.run_once():
        pass


def test_deleting_a_batch_takes_its_detections_and_the_jobs_that_read_them(
    client: TestClient,
    worker: Worker,
    engine: Engine,
    deployment: dict[str, Any],
    paper_csv: str,
    admin_key: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    first = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    second = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    window = client.post(
        "/v1/jobs", json={"deployment_id": deployment["id"], "start": 0, "associator": "kmeans++"}
    )
    assert window.status_code == 202, window.text
    run_all(worker)
    before = row_counts(engine)

    with caplog.at_level(logging.WARNING, logger="roadlink.audit"):
        response = client.delete(f"/v1/deployments/{deployment['id']}/batches/{first['id']}")
    assert response.status_code == 204, response.text
    assert_problem(client.get(f"/v1/batches/{first['id']}"), 404)
    # The first batch's own job and the window over both read its detections: gone with their
    # results. The second batch and its job stay.
    assert_problem(client.get(f"/v1/jobs/{first['job']['id']}"), 404)
    assert_problem(client.get(f"/v1/jobs/{window.json()['id']}"), 404)
    assert client.get(f"/v1/jobs/{second['job']['id']}/result").status_code == 200
    after = row_counts(engine)
    assert after["detection"] == before["detection"] - first["n_detections"]
    assert (after["batch"], after["job"], after["job_result"]) == (1, 1, 1)

    [line] = [r.getMessage() for r in caplog.records if r.name == "roadlink.audit"]
    assert f"API key {key_prefix(admin_key)}" in line
    assert first["id"] in line and deployment["id"] in line
    assert f"{first['n_detections']} detections, 2 finished jobs" in line


def test_data_a_queued_or_running_job_reads_is_not_deleted(
    client: TestClient, engine: Engine, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    before = row_counts(engine)
    for path in (
        f"/v1/deployments/{deployment['id']}/batches/{batch['id']}",
        f"/v1/deployments/{deployment['id']}",
    ):
        problem = assert_problem(client.delete(path), 409)
        assert batch["job"]["id"] in problem["detail"] and "queued" in problem["detail"]
    assert row_counts(engine) == before
    # Once the job is cancelled (or finished), the data can go.
    assert client.post(f"/v1/jobs/{batch['job']['id']}/cancel").status_code == 200
    response = client.delete(f"/v1/deployments/{deployment['id']}/batches/{batch['id']}")
    assert response.status_code == 204, response.text


def test_deleting_a_deployment_takes_everything_of_it(
    client: TestClient,
    worker: Worker,
    engine: Engine,
    deployment: dict[str, Any],
    paper_csv: str,
    caplog: pytest.LogCaptureFixture,
) -> None:
    other = client.post("/v1/deployments", json={"name": "other road"}).json()
    kept = post_csv_batch(client, other["id"], paper_csv, associator="kmeans++")
    post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    hooks = f"/v1/deployments/{deployment['id']}/webhooks"
    assert client.post(hooks, json={"url": "http://127.0.0.1:9/hook"}).status_code == 201
    run_all(worker)  # a job.finished delivery is now in the outbox

    with caplog.at_level(logging.WARNING, logger="roadlink.audit"):
        assert client.delete(f"/v1/deployments/{deployment['id']}").status_code == 204
    assert_problem(client.get(f"/v1/deployments/{deployment['id']}"), 404)
    assert_problem(client.delete(f"/v1/deployments/{deployment['id']}"), 404)
    counts = row_counts(engine)
    assert counts["detection"] == kept["n_detections"]
    assert (counts["batch"], counts["job"], counts["job_result"]) == (1, 1, 1)
    assert (counts["webhook"], counts["webhook_delivery"]) == (0, 0)
    [line] = [r.getMessage() for r in caplog.records if r.name == "roadlink.audit"]
    assert f"deployment {deployment['id']} (1 batches, {kept['n_detections']} detections" in line


def test_a_batch_is_deleted_only_through_its_own_deployment(
    client: TestClient, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv)
    other = client.post("/v1/deployments", json={"name": "other road"}).json()
    assert_problem(client.delete(f"/v1/deployments/{other['id']}/batches/{batch['id']}"), 404)
    assert_problem(client.delete(f"/v1/deployments/{deployment['id']}/batches/{uuid.uuid4()}"), 404)
    assert client.get(f"/v1/batches/{batch['id']}").status_code == 200
