"""The simulator's configuration (`simulation/config.py`): the presets, changed and validated
again, and what is refused."""

import pytest
from pydantic import ValidationError

from roadlink.simulation import PRESETS, SimulationConfig, SlowZone, preset


def test_invalid_configurations_are_refused():
    with pytest.raises(ValidationError):
        SimulationConfig(velocity_range=(0.0, 10.0))
    with pytest.raises(ValidationError):
        SimulationConfig(sensor_positions=[0.0, 0.0])
    with pytest.raises(ValidationError):
        SlowZone(start=5.0, end=1.0, speed_factor=0.5)
    with pytest.raises(ValueError, match="unknown preset"):
        preset("tiny")


def test_the_papers_presets_are_tables_one_to_three_and_overrides_are_validated_again():
    assert [PRESETS[n].velocity_range for n in ("large", "medium", "small")] == [
        (30.0, 80.0),
        (20.0, 50.0),
        (20.0, 40.0),
    ]
    changed = preset("large", miss_probability=0.1)
    assert changed.miss_probability == 0.1
    assert changed.model_dump() == {**PRESETS["large"].model_dump(), "miss_probability": 0.1}
    assert PRESETS["large"].miss_probability == 0.0  # the preset itself is untouched
    with pytest.raises(ValidationError):
        preset("large", velocity_range=(10.0, 5.0))
