"""The SUMO scenarios (`simulation/sumo/scenarios.py`): where sensors may be, and a committed case
for each."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from pydantic import ValidationError

from roadlink.association.csvio import read_detections_csv
from roadlink.simulation.sumo import SUMO_SCENARIOS, Ramp, Signal, sumo_scenario
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


def test_ramps_and_their_added_lanes_keep_clear_of_each_other_and_of_the_road_ends():
    with pytest.raises(ValidationError, match="inside the road"):
        sumo_scenario("sumo-freeflow", ramps=[Ramp(position=2900.0, kind="on")])  # lane to 3150
    with pytest.raises(ValidationError, match="must not overlap"):
        sumo_scenario(
            "sumo-freeflow",
            ramps=[Ramp(position=1070.0, kind="on"), Ramp(position=1400.0, kind="off")],
        )
    with pytest.raises(ValidationError, match="where a sensor stands"):
        sumo_scenario("sumo-freeflow", ramps=[Ramp(position=950.0, kind="off")])
    with pytest.raises(ValidationError, match="clear of signals and bottlenecks"):
        sumo_scenario(
            "sumo-freeflow",
            ramps=[Ramp(position=1070.0, kind="on")],
            signals=[Signal(position=1100.0)],
        )
    with pytest.raises(ValidationError):
        Ramp(position=1000.0, kind="off", share=1.0)


def test_the_committed_junctions_case_loses_and_gains_vehicles_between_sensors():
    d = read_detections_csv(COMMITTED / "sumo-junctions.csv")
    vehicles = d.target.astype(str)
    # Vehicles from the on-ramps (1070 and 2080 m) are first seen at the sensor after them
    # (unless they passed it before the window opened).
    backwards = zip(vehicles[::-1], d.position[::-1], d.timestamp[::-1], strict=True)
    first = {v: (p, t) for v, p, t in backwards}
    assert {p for v, (p, t) in first.items() if "-on" in v and t > 60.0} == {1200.0, 2200.0}
    # A fifth leave before 950 m: fewer there than at 700 m, more again after the on-ramp.
    count = {p: int((d.position == p).sum()) for p in (700.0, 950.0, 1200.0)}
    assert count[950.0] < 0.9 * count[700.0] and count[1200.0] > 1.2 * count[950.0]
