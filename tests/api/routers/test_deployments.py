"""Deployments: create, read, list; declared sensors are validated."""

from __future__ import annotations

from fastapi.testclient import TestClient

from tests.helpers import assert_problem


def test_create_get_and_list(client: TestClient) -> None:
    created = client.post(
        "/v1/deployments",
        json={
            "name": "ring road",
            "sensors": [{"sensor_id": "B", "position": 100}, {"sensor_id": "A", "position": 0}],
        },
    )
    assert created.status_code == 201, created.text
    body = created.json()
    assert body["name"] == "ring road"
    assert [s["sensor_id"] for s in body["sensors"]] == ["A", "B"]  # road order
    assert client.get(f"/v1/deployments/{body['id']}").json() == body
    assert body in client.get("/v1/deployments").json()["items"]


def test_unknown_deployment_is_404(client: TestClient) -> None:
    problem = assert_problem(
        client.get("/v1/deployments/00000000-0000-0000-0000-000000000000"), 404
    )
    assert "no deployment" in problem["detail"]


def test_invalid_sensors_name_the_field(client: TestClient) -> None:
    problem = assert_problem(
        client.post(
            "/v1/deployments",
            json={
                "name": "x",
                "sensors": [{"sensor_id": "A", "position": 0}, {"sensor_id": "A", "position": 5}],
            },
        ),
        422,
    )
    assert "distinct" in problem["detail"]
    problem = assert_problem(client.post("/v1/deployments", json={"sensors": []}), 422)
    assert {e["field"] for e in problem["errors"]} >= {"name", "sensors"}
