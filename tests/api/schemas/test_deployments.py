"""Deployment bodies (`api/schemas/deployments.py`): a name, and, when declared, at least two
sensors with distinct ids at distinct, finite positions; read back from the stored sensors."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any

import pytest
from pydantic import ValidationError

from roadlink.api.schemas import DeploymentCreate, DeploymentRead
from roadlink.db.json_columns import Sensor
from roadlink.db.models import Deployment


def test_the_documented_example_is_a_valid_request() -> None:
    (example,) = DeploymentCreate.model_config["json_schema_extra"]["examples"]  # type: ignore[index]
    created = DeploymentCreate.model_validate(example)
    assert [s.sensor_id for s in created.sensors or []] == ["S1", "S2"]
    assert DeploymentCreate(name="no sensors declared").sensors is None


def _sensors(*pairs: tuple[str, float]) -> list[dict[str, Any]]:
    return [{"sensor_id": name, "position": position} for name, position in pairs]


@pytest.mark.parametrize(
    ("body", "message"),
    [
        ({"name": ""}, "at least 1 character"),
        ({"name": "x" * 201}, "at most 200 characters"),
        ({"name": "road", "sensors": _sensors(("S1", 0.0))}, "at least 2 items"),
        ({"name": "road", "sensors": _sensors(("S1", 0.0), ("S1", 100.0))}, "ids must be distinct"),
        (
            {"name": "road", "sensors": _sensors(("S1", 0.0), ("S2", 0.0))},
            "positions must be distinct",
        ),
        ({"name": "road", "sensors": _sensors(("S1", 0.0), ("S2", float("nan")))}, "finite"),
        ({"name": "road", "sensors": _sensors(("S1", 0.0), ("S2", 2e12))}, "less than or equal"),
        ({"name": "road", "sensors": _sensors(("", 0.0), ("S2", 1.0))}, "at least 1 character"),
        ({"name": "road", "lanes": 2}, "Extra inputs are not permitted"),
    ],
)
def test_a_bad_deployment_is_refused_saying_why(body: dict[str, Any], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        DeploymentCreate.model_validate(body)


def test_a_deployment_is_read_back_with_its_stored_sensors() -> None:
    stored = Deployment(
        id=uuid.uuid4(),
        name="A9",
        sensors=[Sensor("S1", 0.0), Sensor("S2", 100.0)],
        created_at=datetime(2026, 1, 1, tzinfo=UTC),
    )
    shown = DeploymentRead.model_validate(stored).model_dump(mode="json")
    assert shown["sensors"] == [
        {"sensor_id": "S1", "position": 0.0},
        {"sensor_id": "S2", "position": 100.0},
    ]
    assert shown["name"] == "A9" and shown["id"] == str(stored.id)
