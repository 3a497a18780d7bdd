"""The associator catalogue, and simulated batches."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from roadlink.association.associators import ASSOCIATORS, DEFAULT_ASSOCIATOR
from roadlink.queue.worker import Worker
from tests.helpers import assert_problem


def test_associators_list_every_registered_one_with_its_parameters(client: TestClient) -> None:
    listed = {a["name"]: a for a in client.get("/v1/associators").json()}
    assert set(listed) == set(ASSOCIATORS)
    assert [n for n, a in listed.items() if a["default"]] == [DEFAULT_ASSOCIATOR]
    for name, cls in ASSOCIATORS.items():
        assert listed[name]["parameters"] == cls.parameters_schema()
        assert listed[name]["needs_labels"] == cls.needs_labels


def test_a_simulation_makes_a_labelled_batch_and_can_associate_it(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    created = client.post(
        "/v1/simulations",
        json={
            "deployment_id": deployment["id"],
            "preset": "small",
            "seed": 2,
            "config": {"n_targets": 6, "miss_probability": 0.1},
            "associate": {"associator": "kmeans++", "params": {"n_targets": 6}},
        },
    )
    assert created.status_code == 201, created.text
    batch = created.json()
    assert batch["source"] == "simulation"
    assert 0 < batch["n_detections"] <= 60 and batch["n_labelled"] == batch["n_detections"]
    assert worker.run_once()
    result = client.get(f"/v1/jobs/{batch['job']['id']}/result").json()
    assert result["n_targets"] == 6 and result["metrics"] is not None


def test_a_simulation_uses_the_deployments_declared_sensors(
    client: TestClient, worker: Worker
) -> None:
    sensors = [{"sensor_id": f"loop-{k}", "position": 250.0 * k} for k in range(4)]
    deployment = client.post("/v1/deployments", json={"name": "d", "sensors": sensors}).json()
    batch = client.post(
        "/v1/simulations",
        json={"deployment_id": deployment["id"], "associate": {"associator": "kmeans++"}},
    ).json()
    assert batch["n_detections"] == 40
    assert worker.run_once()
    result = client.get(f"/v1/jobs/{batch['job']['id']}/result").json()
    used = {d["sensor_id"] for t in result["targets"] for d in t["detections"]}
    assert used == {s["sensor_id"] for s in sensors}


def test_invalid_simulations(client: TestClient, deployment: dict[str, Any]) -> None:
    problem = assert_problem(
        client.post(
            "/v1/simulations",
            json={"deployment_id": deployment["id"], "config": {"velocity_range": [50, 10]}},
        ),
        422,
    )
    assert "velocity_range" in problem["detail"] or problem["errors"]
    problem = assert_problem(
        client.post(
            "/v1/simulations",
            json={"deployment_id": deployment["id"], "config": {"n_targets": 1_000_000}},
        ),
        422,
    )
    assert "roadlink simulate" in problem["detail"]
    assert_problem(
        client.post("/v1/simulations", json={"deployment_id": deployment["id"], "preset": "huge"}),
        422,
    )
