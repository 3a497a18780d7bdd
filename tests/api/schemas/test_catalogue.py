"""The catalogue's bodies (`api/schemas/catalogue.py`): a simulation request names a preset and
overrides any simulator setting, each optional, so the API cannot drift from the simulator."""

from __future__ import annotations

import uuid

import pytest
from pydantic import ValidationError

from roadlink.api.schemas import SimulationCreate, SimulationOverrides
from roadlink.simulation import PRESETS, SimulationConfig


def test_every_simulator_setting_can_be_overridden_and_none_must_be() -> None:
    assert set(SimulationOverrides.model_fields) == set(SimulationConfig.model_fields)
    for name, field in SimulationOverrides.model_fields.items():
        assert field.default is None, name
        assert field.description == SimulationConfig.model_fields[name].description
    assert SimulationOverrides().model_dump(exclude_none=True) == {}


def test_a_simulation_request_defaults_and_its_example() -> None:
    deployment = uuid.uuid4()
    asked = SimulationCreate(deployment_id=deployment)
    assert (asked.preset, asked.seed, asked.associate) == ("large", 0, None)
    (example,) = SimulationCreate.model_config["json_schema_extra"]["examples"]  # type: ignore[index]
    documented = SimulationCreate.model_validate(example)
    assert documented.config.model_dump(exclude_none=True) == {"n_targets": 10}  # type: ignore[attr-defined]
    assert set(SimulationCreate.model_json_schema()["properties"]["preset"]["enum"]) == set(PRESETS)


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"preset": "huge"}, "preset"),
        ({"seed": -1}, "greater than or equal to 0"),
        ({"config": {"n_lanes": 2}}, "Extra inputs are not permitted"),
        ({"config": {"n_targets": "many"}}, "n_targets"),
    ],
)
def test_a_bad_simulation_request_is_refused(change: dict[str, object], message: str) -> None:
    with pytest.raises(ValidationError, match=message):
        SimulationCreate.model_validate({"deployment_id": str(uuid.uuid4()), **change})
