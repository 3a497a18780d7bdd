"""Idempotency-Key on job creation: a retry returns the original job, nothing is enqueued twice,
the same key with another body is 422; keys are forgotten after the retention, not before."""

from __future__ import annotations

from datetime import timedelta
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, select, update

from roadlink.db.engine import make_session_factory
from roadlink.db.models import Batch, JobIdempotencyKey, utcnow
from roadlink.services.idempotency import forget_expired_keys
from roadlink.settings import Settings
from tests.helpers import MakeKey, assert_problem, bearer, row_counts


def _batch(client: TestClient, deployment: dict[str, Any], csv: str, key: str | None) -> Any:
    headers = {"content-type": "text/csv", **({"Idempotency-Key": key} if key else {})}
    return client.post(f"/v1/deployments/{deployment['id']}/batches", content=csv, headers=headers)


def test_a_retried_job_request_returns_the_original_job(
    client: TestClient, engine: Engine, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = _batch(client, deployment, paper_csv, None).json()
    body = {"batch_id": batch["id"], "associator": "kmeans"}
    first = client.post("/v1/jobs", json=body, headers={"Idempotency-Key": "job-1"})
    assert first.status_code == 202 and "idempotent-replayed" not in first.headers
    before = row_counts(engine)
    # The same request again, differently spelled (key order, spacing): the same job back.
    again = client.post(
        "/v1/jobs",
        content=f'{{ "associator": "kmeans",  "batch_id": "{batch["id"]}" }}',
        headers={"Idempotency-Key": "job-1", "content-type": "application/json"},
    )
    assert again.status_code == 202
    assert again.headers["idempotent-replayed"] == "true"
    assert again.json()["id"] == first.json()["id"]
    assert row_counts(engine) == before
    # The same key with another body is refused; a new key makes a new job.
    other = client.post(
        "/v1/jobs", json={**body, "associator": "kmeans++"}, headers={"Idempotency-Key": "job-1"}
    )
    problem = assert_problem(other, 422)
    assert "job-1" in problem["detail"] and first.json()["id"] in problem["detail"]
    assert problem["errors"][0]["field"] == "Idempotency-Key"
    assert row_counts(engine) == before
    fresh = client.post("/v1/jobs", json=body, headers={"Idempotency-Key": "job-2"})
    assert fresh.status_code == 202 and fresh.json()["id"] != first.json()["id"]
    assert row_counts(engine)["job"] == before["job"] + 1


def test_job_keys_belong_to_the_api_key_that_sent_them(
    client: TestClient, make_key: MakeKey, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = _batch(client, deployment, paper_csv, None).json()
    body = {"batch_id": batch["id"]}
    mine = client.post("/v1/jobs", json=body, headers={"Idempotency-Key": "1"})
    theirs = client.post(
        "/v1/jobs", json=body, headers={"Idempotency-Key": "1", **bearer(make_key("read"))}
    )
    assert mine.status_code == theirs.status_code == 202
    assert mine.json()["id"] != theirs.json()["id"]


def test_keys_are_kept_for_the_retention_then_forgotten(
    client: TestClient,
    engine: Engine,
    settings: Settings,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    batch = _batch(client, deployment, paper_csv, "batch-key").json()
    job = client.post("/v1/jobs", json={"batch_id": batch["id"]}, headers={"Idempotency-Key": "j"})
    sessions = make_session_factory(engine)
    # Nothing is forgotten within the retention (24 hours by default)...
    forgotten = forget_expired_keys(sessions, settings)
    assert (forgotten.batches, forgotten.jobs) == (0, 0)
    replay = _batch(client, deployment, paper_csv, "batch-key")
    assert replay.headers["idempotent-replayed"] == "true"
    # ...and everything older is; the batch and the job themselves stay.
    aged = utcnow() - timedelta(hours=settings.idempotency_hours, minutes=1)
    with sessions.begin() as session:
        session.execute(update(Batch).values(created_at=aged))
        session.execute(update(JobIdempotencyKey).values(created_at=aged))
    forgotten = forget_expired_keys(sessions, settings)
    assert (forgotten.batches, forgotten.jobs) == (1, 1)
    with sessions() as session:
        assert session.scalars(select(Batch.idempotency_key)).all() == [None]
    assert client.get(f"/v1/jobs/{job.json()['id']}").status_code == 200
    again = _batch(client, deployment, paper_csv, "batch-key")
    assert again.status_code == 201 and again.json()["id"] != batch["id"]
