"""The webhook outbox: a finished job's event written for each webhook of its deployment, in the
transaction that finishes it; claiming a due delivery, with the ids its log line carries
(sending and retrying: tests/queue/test_webhook_dispatch.py); on SQLite and PostgreSQL."""

from __future__ import annotations

import json
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, select

from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import WebhookDelivery
from roadlink.queue.webhooks import claim_due_delivery
from roadlink.queue.worker import Worker
from tests.helpers import post_csv_batch

CSV = "position,velocity,timestamp\n0,30,1\n100,30,4.3\n0,20,2\n100,20,7\n"


def test_a_finished_job_writes_one_delivery_per_webhook_of_its_deployment_to_claim(
    client: TestClient, worker: Worker, engine: Engine, deployment: dict[str, Any]
) -> None:
    def hook(road: str) -> str:
        made = client.post(f"/v1/deployments/{road}/webhooks", json={"url": "https://a.b/"})
        return str(made.json()["id"])

    mine = {hook(deployment["id"]), hook(deployment["id"])}
    other = client.post("/v1/deployments", json={"name": "elsewhere"}).json()["id"]
    hook(other)
    batch = post_csv_batch(client, deployment["id"], CSV, associator="kmeans", request_id="hook-9")
    sessions = make_session_factory(engine)
    with sessions() as session:
        assert session.scalars(select(WebhookDelivery)).all() == []  # not before it finishes
    assert worker.run_once()

    with sessions() as session:
        written = session.scalars(select(WebhookDelivery)).all()
    assert {str(d.webhook_id) for d in written} == mine and len(written) == 2
    assert len({d.event_id for d in written}) == 1  # one event, sent to each webhook
    event = json.loads(written[0].payload)
    assert (event["type"], event["deployment_id"]) == ("job.finished", deployment["id"])
    assert event["data"]["job"]["id"] == batch["job"]["id"]
    assert event["data"]["job"]["state"] == "succeeded"

    claimed = []
    for _ in range(3):
        with transaction(sessions) as session:
            claimed.append(claim_due_delivery(session, claim_seconds=60))
    first, second, none = claimed
    assert none is None  # both are claimed for the next 60 s
    assert first is not None and second is not None and first.id != second.id
    assert (first.attempt, first.url) == (1, "https://a.b/")
    assert first.context == {
        "deployment_id": deployment["id"],
        "job_id": batch["job"]["id"],
        "request_id": "hook-9",
    }
