"""ROADLINK_RETENTION_DAYS: what is older than the period goes, in chunks; what is newer, and
old batches that a queued job still reads, stay; on SQLite and PostgreSQL."""

from __future__ import annotations

import uuid
from datetime import timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, update

from roadlink.db import lifecycle
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import Batch, Job, WebhookDelivery, utcnow
from roadlink.queue import retention
from roadlink.queue.retention import delete_expired
from roadlink.queue.worker import Worker
from tests.helpers import post_csv_batch, row_counts


def test_retention_deletes_what_is_older_than_the_period(
    client: TestClient,
    worker: Worker,
    engine: Engine,
    deployment: dict[str, Any],
    paper_csv: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(lifecycle, "CHUNK", 7)  # several chunks per batch of 100 detections
    monkeypatch.setattr(retention, "BATCHES_PER_ROUND", 1)  # rounds of held batches only too
    assert (
        client.post(
            f"/v1/deployments/{deployment['id']}/webhooks", json={"url": "http://127.0.0.1:9/"}
        ).status_code
        == 201
    )
    old = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    new = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    while worker.run_once():
        pass
    # Two more batches, each read by its queued job (with the one batch a round, retention
    # must look past rounds of held batches to find the deletable one, whatever their order).
    held = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans++")
    sessions = make_session_factory(engine)
    now = utcnow()
    with transaction(sessions) as session:
        # Everything was made 40 days ago, but for the second batch and its job (yesterday).
        session.execute(update(Batch).values(created_at=now - timedelta(days=40)))
        session.execute(update(Job).values(finished_at=now - timedelta(days=40)))
        session.execute(update(WebhookDelivery).values(created_at=now - timedelta(days=40)))
        session.execute(
            update(Batch)
            .where(Batch.id == uuid.UUID(new["id"]))
            .values(created_at=now - timedelta(days=1))
        )
        session.execute(
            update(Job)
            .where(Job.id == uuid.UUID(new["job"]["id"]))
            .values(finished_at=now - timedelta(days=1))
        )
    before = row_counts(engine)
    assert before["webhook_delivery"] == 2

    expired = delete_expired(sessions, days=30, now=now)

    assert (expired.jobs, expired.batches, expired.deliveries) == (1, 1, 2)
    assert expired.detections == old["n_detections"]
    after = row_counts(engine)
    assert after["batch"] == 3 and after["job"] == 3 and after["job_result"] == 1
    assert after["detection"] == before["detection"] - old["n_detections"]
    assert client.get(f"/v1/batches/{old['id']}").status_code == 404
    assert client.get(f"/v1/jobs/{old['job']['id']}").status_code == 404
    assert client.get(f"/v1/jobs/{new['job']['id']}/result").status_code == 200
    # The old batch a queued job reads is kept, and goes on a pass after the job finished.
    assert client.get(f"/v1/batches/{held['id']}").status_code == 200
    while worker.run_once():
        pass
    later = delete_expired(sessions, days=30, now=now)
    assert (later.jobs, later.batches) == (0, 2)
    assert delete_expired(sessions, days=30, now=now) == later.__class__(0, 0, 0, 0)
