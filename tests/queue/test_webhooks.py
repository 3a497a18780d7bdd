"""The webhook outbox: a finished job's event written for each webhook of its deployment, in the
transaction that finishes it; claiming a due delivery, with the ids its log line carries
(sending and retrying: tests/queue/test_webhook_dispatch.py); a live association's vehicle
events, written by the step that publishes them; on SQLite and PostgreSQL."""

from __future__ import annotations

import json
from typing import Any

from fastapi.testclient import TestClient
from sqlalchemy import Engine, select

from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import WebhookDelivery
from roadlink.queue.webhooks import claim_due_delivery
from roadlink.queue.worker import Worker
from roadlink.simulation import preset, simulate
from tests.helpers import detection_rows, post_csv_batch

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


def test_a_live_association_writes_a_vehicle_event_per_vehicle_it_publishes(
    client: TestClient, worker: Worker, engine: Engine, deployment: dict[str, Any]
) -> None:
    base = f"/v1/deployments/{deployment['id']}"
    wants = client.post(
        f"{base}/webhooks", json={"url": "https://a.b/", "event_types": ["vehicle.published"]}
    ).json()["id"]
    client.post(f"{base}/webhooks", json={"url": "https://c.d/"})  # job.finished only
    client.put(f"{base}/live", json={"lateness": 5})
    d = simulate(preset("large", n_targets=3), seed=4).detections
    client.post(f"{base}/batches", json={"detections": detection_rows(d)})  # no job asked for
    client.post(f"{base}/live/flush")
    while worker.run_live_once():
        pass

    sessions = make_session_factory(engine)
    with sessions() as session:
        written = session.scalars(select(WebhookDelivery).order_by(WebhookDelivery.created_at))
        events = [(str(w.webhook_id), w.event_type, json.loads(w.payload)) for w in written]
    assert [(hook, kind) for hook, kind, _ in events] == [(wants, "vehicle.published")] * 3
    assert len({event["id"] for _, _, event in events}) == 3
    vehicles = [event["data"]["vehicle"] for _, _, event in events]
    assert sorted(v["vehicle_id"] for v in vehicles) == ["V1", "V2", "V3"]
    # The event's vehicle is the feed's, which its link opens (the feed also names the
    # features a detection does not have, as null).
    for vehicle in vehicles:
        (shown, *_) = client.get(vehicle["links"]["feed"]).json()["items"]
        for item in shown["detections"]:
            for feature in [k for k, v in item.items() if v is None]:
                del item[feature]
        assert shown == {k: v for k, v in vehicle.items() if k != "links"}
    with transaction(sessions) as session:
        claimed = claim_due_delivery(session, claim_seconds=60)
    assert claimed is not None and claimed.context == {"deployment_id": deployment["id"]}
