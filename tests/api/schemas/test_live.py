"""Live association bodies (`api/schemas/live.py`): a start asks for a known associator's name,
its parameters and a finite lateness >= 0, with defaults for each; a detection of the feed keeps
the features its gateway sent."""

from __future__ import annotations

import uuid

import pytest
from pydantic import ValidationError

from roadlink.api.schemas.live import DEFAULT_LATENESS_SECONDS, LiveDetectionRead, LiveStart
from roadlink.association.associators import DEFAULT_ASSOCIATOR


def test_the_documented_example_and_the_defaults() -> None:
    (example,) = LiveStart.model_config["json_schema_extra"]["examples"]  # type: ignore[index]
    assert LiveStart.model_validate(example).lateness == 15.0
    empty = LiveStart()
    assert (empty.associator, empty.params, empty.lateness) == (
        DEFAULT_ASSOCIATOR,
        {},
        DEFAULT_LATENESS_SECONDS,
    )


@pytest.mark.parametrize(
    ("body", "field"),
    [
        ({"lateness": -1}, "lateness"),
        ({"lateness": float("inf")}, "lateness"),
        ({"lateness": 2e9}, "lateness"),
        ({"associator": 3}, "associator"),
        ({"late": 1}, "late"),  # unknown fields are refused, not ignored
    ],
)
def test_a_bad_start_names_its_field(body: dict[str, object], field: str) -> None:
    with pytest.raises(ValidationError) as raised:
        LiveStart.model_validate(body)
    assert raised.value.errors()[0]["loc"] == (field,)


def test_a_feed_detection_keeps_what_its_gateway_sent() -> None:
    batch = uuid.uuid4()
    read = LiveDetectionRead.model_validate(
        {
            "detection_id": "d1",
            "batch_id": str(batch),
            "sensor_id": "S1",
            "position": 0.0,
            "velocity": 30.0,
            "timestamp": 1.5,
            "lane": 2,
            "colour": "red",
        }
    )
    assert read.batch_id == batch and read.lane == 2 and read.target is None
    assert read.model_dump()["colour"] == "red"
