"""Plain helpers that the tests share: building request bodies, checking problem details,
counting rows. Fixtures live in conftest.py files; these are imported like any module."""

from __future__ import annotations

import uuid
from collections.abc import Callable
from typing import Any

from sqlalchemy import Engine, func, select

from roadlink.association.detections import Detections
from roadlink.db.models import Base

MakeKey = Callable[..., str]
"""The `make_key` fixture: (scope, *deployment ids) -> a new API key."""

EnqueueJob = Callable[..., uuid.UUID]
"""The queue tests' `enqueue` fixture: enqueue a job over a stored batch, return its id."""


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


def bearer(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def row_counts(engine: Engine) -> dict[str, int]:
    """The number of rows in every table of the schema."""
    with engine.connect() as connection:
        return {
            name: int(connection.scalar(select(func.count()).select_from(table)) or 0)
            for name, table in Base.metadata.tables.items()
        }
