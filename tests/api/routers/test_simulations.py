"""Simulated batches (`api/routers/simulations.py`): labelled detections from the simulator, stored
as a batch of a deployment, with its sensors and the detector features asked for."""

from __future__ import annotations

from typing import Any

from fastapi.testclient import TestClient

from roadlink.api.routers.simulations import _with_declared_sensor_ids
from roadlink.db.json_columns import Sensor
from roadlink.queue.worker import Worker
from roadlink.simulation import preset, simulate
from tests.helpers import assert_problem


def test_a_simulation_makes_a_labelled_batch_and_can_associate_it(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    batch = _simulate(
        client,
        deployment,
        seed=2,
        config={"n_targets": 6, "miss_probability": 0.1},
        params={"n_targets": 6},
    )
    assert batch["source"] == "simulation"
    assert 0 < batch["n_detections"] <= 60 and batch["n_labelled"] == batch["n_detections"]
    assert worker.run_once()
    result = client.get(f"/v1/jobs/{batch['job']['id']}/result").json()
    assert result["n_targets"] == 6 and result["metrics"] is not None


def test_a_simulation_with_features_stores_them_for_its_job(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    batch = _simulate(
        client,
        deployment,
        seed=4,
        config={"lanes": 2, "vehicle_lengths": True, "vehicle_classes": True},
        params={"use_length": True},
    )
    assert worker.run_once()
    job = client.get(f"/v1/jobs/{batch['job']['id']}").json()
    assert job["state"] == "succeeded", job
    result = client.get(f"/v1/jobs/{batch['job']['id']}/result").json()
    rows = [d for t in result["targets"] for d in t["detections"]]
    assert all(d["lane"] in (0, 1) and d["length"] > 0 and d["vehicle_class"] for d in rows)


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


def test_a_simulation_takes_the_detector_feature_settings(
    client: TestClient, deployment: dict[str, Any]
) -> None:
    config = {"lanes": 3, "vehicle_lengths": True, "vehicle_classes": True, "length_noise": 0.05}
    created = client.post(
        "/v1/simulations",
        json={"deployment_id": deployment["id"], "preset": "small", "config": config},
    )
    assert created.status_code == 201, created.text
    assert created.json()["n_detections"] == 100


def test_invalid_feature_settings_name_their_field(
    client: TestClient, deployment: dict[str, Any]
) -> None:
    for config, field in [
        ({"lanes": 0}, "config.lanes"),
        ({"lane_change_probability": 0.3}, "config.lane_change_probability"),
        ({"length_noise": 0.05}, "config.length_noise"),
    ]:
        problem = assert_problem(
            client.post(
                "/v1/simulations", json={"deployment_id": deployment["id"], "config": config}
            ),
            422,
        )
        assert [e["field"] for e in problem["errors"]] == [field], problem


def test_declared_sensor_names_keep_the_simulated_features() -> None:
    config = preset("small", sensor_positions=[0.0, 250.0], lanes=2, vehicle_lengths=True)
    simulated = simulate(config, seed=1).detections
    declared = [
        Sensor(sensor_id="loop-a", position=0.0),
        Sensor(sensor_id="loop-b", position=250.0),
    ]
    named = _with_declared_sensor_ids(simulated, declared)
    assert set(named.sensor_id) == {"loop-a", "loop-b"}
    assert named.lane.tolist() == simulated.lane.tolist()
    assert named.length.tolist() == simulated.length.tolist()


def _simulate(
    client: TestClient,
    deployment: dict[str, Any],
    *,
    seed: int,
    config: dict[str, Any],
    params: dict[str, Any],
) -> dict[str, Any]:
    """A small simulated batch in the deployment, with a kmeans++ job: the created batch."""
    created = client.post(
        "/v1/simulations",
        json={
            "deployment_id": deployment["id"],
            "preset": "small",
            "seed": seed,
            "config": config,
            "associate": {"associator": "kmeans++", "params": params},
        },
    )
    assert created.status_code == 201, created.text
    batch: dict[str, Any] = created.json()
    return batch
