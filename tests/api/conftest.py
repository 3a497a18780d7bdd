"""Helpers for API tests (the security tests use them too)."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.db.apikeys import create_api_key
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import ApiKeyScope
from roadlink.simulation import preset, simulate


@pytest.fixture
def paper_batch() -> Detections:
    """The paper's large scenario: 10 targets, 10 sensors 100 m apart, labelled."""
    return simulate(preset("large"), seed=5).detections


@pytest.fixture
def paper_csv(paper_batch: Detections) -> str:
    return write_detections_csv(paper_batch)


@pytest.fixture
def deployment(client: TestClient) -> dict[str, Any]:
    response = client.post("/v1/deployments", json={"name": "test road"})
    assert response.status_code == 201, response.text
    return dict(response.json())


def detection_rows(detections: Detections) -> list[dict[str, Any]]:
    """Detections as the JSON batch body lists them."""
    d = detections
    return [
        {
            "position": float(d.position[i]),
            "velocity": float(d.velocity[i]),
            "timestamp": float(d.timestamp[i]),
            "sensor_id": d.sensor_id[i],
            "detection_id": d.detection_id[i],
            "target": d.target[i],
        }
        for i in range(len(d))
    ]


def assert_problem(response: Any, status: int) -> dict[str, Any]:
    """The response is problem details with this status; returns its body."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    body = dict(response.json())
    assert body["status"] == status and body["title"] and body["detail"]
    return body


MakeKey = Callable[..., str]


@pytest.fixture
def make_key(engine: Engine) -> MakeKey:
    """Create a key of `scope` (ingest keys name their deployments); returns the key."""

    def make(scope: str, *deployments: str) -> str:
        with transaction(make_session_factory(engine)) as session:
            return create_api_key(
                session,
                scope=ApiKeyScope(scope),
                deployment_ids=[uuid.UUID(d) for d in deployments],
            ).key

    return make
