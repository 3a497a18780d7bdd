"""A deployment's live association over HTTP: start, status, stop, flush, the vehicles feed by
cursor (with ?wait=) and as Server-Sent Events resumed from Last-Event-ID; deleted with its
deployment."""

from __future__ import annotations

from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from roadlink.association.detections import Detections
from roadlink.queue.worker import Worker
from roadlink.simulation import preset, simulate
from tests.helpers import assert_problem, detection_rows, row_counts


def _traffic() -> Detections:
    return simulate(preset("large", n_targets=12, start_time_range=(1.0, 60.0)), seed=3).detections


def _post(client: TestClient, deployment: str, d: Detections) -> None:
    response = client.post(
        f"/v1/deployments/{deployment}/batches", json={"detections": detection_rows(d)}
    )
    assert response.status_code == 201, response.text


def _drain(worker: Worker) -> None:
    while worker.run_live_once():
        pass


def _all_vehicles(client: TestClient, deployment: str) -> list[dict[str, Any]]:
    """Every vehicle published so far, following `next` as a list's pages are followed; a feed
    has no last page, so it stops at the first empty one."""
    vehicles: list[dict[str, Any]] = []
    link = f"/v1/deployments/{deployment}/vehicles?limit=5"
    while True:
        response = client.get(link)
        page = response.json()
        assert response.headers["Link"] == f'<{page["next"]}>; rel="next"'
        if not page["items"]:
            return vehicles
        vehicles += page["items"]
        link = page["next"]


def test_start_feed_flush_and_stop(
    client: TestClient, deployment: dict[str, Any], worker: Worker
) -> None:
    base = f"/v1/deployments/{deployment['id']}"
    assert_problem(client.get(f"{base}/live"), 404)
    assert_problem(client.get(f"{base}/live/plot"), 404)
    started = client.put(f"{base}/live", json={"associator": "assignment", "lateness": 5})
    assert started.status_code == 200, started.text
    assert started.json()["state"] == "running" and started.json()["data_clock"] is None
    d = _traffic()
    sensors = sorted(set(d.sensor_id.tolist()))
    for sensor in sensors:  # one batch per sensor
        _post(client, deployment["id"], d.take((d.sensor_id == sensor).nonzero()[0]))
    status = client.get(f"{base}/live").json()
    assert status["data_clock"] == pytest.approx(float(d.timestamp.max()))
    assert status["pending"] is True
    _drain(worker)
    flushed = client.post(f"{base}/live/flush")
    assert flushed.status_code == 200 and flushed.json()["pending"] is True
    _drain(worker)
    status = client.get(f"{base}/live").json()
    assert status["pending"] is False and status["open_tracks"] == 0
    vehicles = _all_vehicles(client, deployment["id"])
    assert status["vehicles_published"] == len(vehicles) == 12
    assert [v["vehicle_id"] for v in vehicles] == [f"V{k}" for k in range(1, 13)]
    first = vehicles[0]
    assert first["final"] is True and first["revision"] == 1 and 0 < first["confidence"] <= 1
    assert len(first["detections"]) == 10
    assert {"detection_id", "batch_id", "sensor_id", "position", "velocity", "timestamp"} <= set(
        first["detections"][0]
    )
    # Nothing after the last cursor; a wait that finds nothing answers empty, same cursor.
    last = vehicles[-1]["cursor"]
    tail = client.get(f"{base}/vehicles?after={last}&wait=0.1").json()
    assert tail == {
        "items": [],
        "next_cursor": last,
        "next": f"{base}/vehicles?wait=0.1&after={last}",
    }
    plot = client.get(f"{base}/live/plot?vehicles=5&format=svg")
    assert plot.status_code == 200 and plot.headers["content-type"] == "image/svg+xml"
    assert plot.text.count('id="target-T') == 5  # one line per vehicle
    stopped = client.delete(f"{base}/live")
    assert stopped.status_code == 200 and stopped.json()["state"] == "stopped"
    assert len(_all_vehicles(client, deployment["id"])) == 12  # what was published stays
    assert_problem(client.post(f"{base}/live/flush"), 409)
    # Restarted, it numbers on and publishes nothing twice.
    assert client.put(f"{base}/live", json={}).json()["state"] == "running"
    _drain(worker)
    assert client.get(f"{base}/live").json()["vehicles_published"] == 12


def test_bad_requests_name_the_field_and_change_nothing(
    client: TestClient, deployment: dict[str, Any]
) -> None:
    base = f"/v1/deployments/{deployment['id']}"
    problem = assert_problem(client.put(f"{base}/live", json={"associator": "nope"}), 422)
    assert "nope" in problem["detail"]
    problem = assert_problem(client.put(f"{base}/live", json={"lateness": -1}), 422)
    assert problem["errors"][0]["field"] == "lateness"
    problem = assert_problem(client.put(f"{base}/live", json={"params": {"x": 1}}), 422)
    assert_problem(client.get(f"{base}/live"), 404)  # nothing was started
    problem = assert_problem(client.get(f"{base}/vehicles?after=abc"), 422)
    assert problem["errors"][0]["field"] == "after"
    for limit in ("0", "1001"):  # the lists' bounds
        problem = assert_problem(client.get(f"{base}/vehicles?limit={limit}"), 422)
        assert problem["errors"][0]["field"] == "limit"
    unknown = "/v1/deployments/00000000-0000-0000-0000-000000000000"
    assert_problem(client.put(f"{unknown}/live", json={}), 404)
    assert_problem(client.get(f"{unknown}/vehicles"), 404)
    assert_problem(client.get(f"{unknown}/vehicles/stream"), 404)


def _all_published(client: TestClient, deployment: str, worker: Worker) -> str:
    """Start a live association, post its whole traffic, flush and step until it is done; the
    deployment's path."""
    base = f"/v1/deployments/{deployment}"
    client.put(f"{base}/live", json={"lateness": 5})
    _post(client, deployment, _traffic())
    client.post(f"{base}/live/flush")
    _drain(worker)
    return base


def _events(text: str) -> list[tuple[str, str]]:
    """(id, data) of every event of an SSE body."""
    found = []
    for block in text.split("\n\n"):
        fields = dict(line.split(": ", 1) for line in block.splitlines() if ": " in line)
        if "id" in fields:
            found.append((fields["id"], fields["data"]))
    return found


def test_the_event_stream_resumes_after_last_event_id(
    client: TestClient, deployment: dict[str, Any], worker: Worker
) -> None:
    base = _all_published(client, deployment["id"], worker)
    whole = client.get(f"{base}/vehicles/stream?idle_timeout=0.2")
    assert whole.status_code == 200
    assert whole.headers["content-type"].startswith("text/event-stream")
    events = _events(whole.text)
    assert len(events) == 12
    # A client that saw the first five reconnects with the id of the fifth.
    resumed = client.get(
        f"{base}/vehicles/stream?idle_timeout=0.2", headers={"Last-Event-ID": events[4][0]}
    )
    assert _events(resumed.text) == events[5:]


def test_deleting_the_deployment_deletes_its_live_association(
    client: TestClient, deployment: dict[str, Any], worker: Worker, engine: Engine
) -> None:
    base = _all_published(client, deployment["id"], worker)
    counts = row_counts(engine)
    assert counts["live_vehicle"] == 12 and counts["live_settled_detection"] > 0
    assert client.delete(base).status_code == 204
    counts = row_counts(engine)
    assert counts["live_association"] == counts["live_vehicle"] == 0
    assert counts["live_settled_detection"] == 0
    assert_problem(client.get(f"{base}/vehicles"), 404)
