"""The SUMO scenarios (`simulation/sumo/scenarios.py`): where sensors may be, and a committed case
for each."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from roadlink.association.csvio import read_detections_csv
from roadlink.simulation.sumo import SUMO_SCENARIOS, Signal, sumo_scenario
from tests.helpers import travel_times

COMMITTED = Path(__file__).parents[2] / "data" / "sumo"


def test_scenarios_reject_sensors_off_the_road():
    with pytest.raises(ValidationError, match="inside the road"):
        sumo_scenario("sumo-freeflow", sensor_positions=[100.0, 3000.0])
    with pytest.raises(ValueError, match="unknown SUMO scenario 'nope'"):
        sumo_scenario("nope")


def test_every_scenario_has_a_committed_case():
    assert sorted(p.stem for p in COMMITTED.glob("*.csv")) == sorted(SUMO_SCENARIOS)


def test_signals_stand_inside_the_road_apart_from_each_other_and_from_the_sensors():
    with pytest.raises(ValidationError, match="distinct positions inside the road"):
        sumo_scenario("sumo-freeflow", signals=[Signal(position=3000.0)])
    with pytest.raises(ValidationError, match="distinct positions inside the road"):
        sumo_scenario("sumo-freeflow", signals=[Signal(position=640.0), Signal(position=640.0)])
    with pytest.raises(ValidationError, match="where a sensor does"):
        sumo_scenario("sumo-freeflow", signals=[Signal(position=450.0)])
    with pytest.raises(ValidationError):
        Signal(position=640.0, red=0.0)


def test_the_committed_arterial_case_shows_its_traffic_lights():
    """Vehicles that meet a red light wait: over a segment with a signal the travel times spread
    from the free-flow time to the red time and more; elsewhere they stay near it."""
    d = read_detections_csv(COMMITTED / "sumo-arterial.csv")
    free = travel_times(d, 100.0, 250.0)
    lights = travel_times(d, 550.0, 700.0)
    assert np.percentile(free, 90) < 1.5 * np.median(free)
    assert np.percentile(lights, 10) < 1.3 * np.median(free)  # through on green
    assert np.percentile(lights, 90) > np.median(free) + 25.0  # most of a 35 s red
