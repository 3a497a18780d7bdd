"""The SUMO scenarios (`simulation/sumo/scenarios.py`): where sensors may be, and a committed case
for each."""

from __future__ import annotations

from pathlib import Path

import pytest
from pydantic import ValidationError

from roadlink.simulation.sumo import SUMO_SCENARIOS, sumo_scenario

COMMITTED = Path(__file__).parents[2] / "data" / "sumo"


def test_scenarios_reject_sensors_off_the_road():
    with pytest.raises(ValidationError, match="inside the road"):
        sumo_scenario("sumo-freeflow", sensor_positions=[100.0, 3000.0])
    with pytest.raises(ValueError, match="unknown SUMO scenario 'nope'"):
        sumo_scenario("nope")


def test_every_scenario_has_a_committed_case():
    assert sorted(p.stem for p in COMMITTED.glob("*.csv")) == sorted(SUMO_SCENARIOS)
