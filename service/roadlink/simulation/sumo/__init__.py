"""Realistic traffic from Eclipse SUMO: car-following, lane changes, queues, and loop detectors.

The paper's simulator drives independent targets at their own speeds; real traffic is not like
that. Here a straight multi-lane motorway is simulated with SUMO (Krauss car-following, LC2013 lane
changing, a mix of cars and trucks with a spread of desired speeds, Poisson arrivals, optionally a
lane drop or a slow section that causes queues and stop-and-go waves). At every sensor position an
`instantInductionLoop` sits on each lane; each vehicle entering one writes its passing time and
speed, with the vehicle id, which becomes the ground-truth label. One sensor is all of its lanes.

Detections are kept within a time window opened after a warm-up (so the road is already full, as
in real data), which cuts tracks at both ends: some vehicles pass only the last sensors, some only
the first. Detector faults (misses, false alarms, duplicates, measurement noise) are applied to
the parsed detections afterwards by the fault model every simulator shares
(`roadlink.simulation.faults`), with their own seeded random generator.

The package is in three parts:
- `scenarios`: what is simulated (road, sensors, traffic, faults) and the named scenarios;
- `files`: SUMO's input files written from a scenario, and its detector output read back;
- `runner`: finding SUMO, running it, and applying the faults.

It imports without SUMO; only `run_sumo` needs it (PyPI `eclipse-sumo`, the optional extra
`roadlink[sumo]`). Everything else is plain Python and tested without SUMO.
"""

from roadlink.simulation.faults import DetectorFaults
from roadlink.simulation.sumo.files import (
    MIN_REPORTED_SPEED,
    connections_xml,
    detectors_xml,
    lane_starts,
    network_xml,
    parse_detector_output,
    routes_xml,
    signals_xml,
)
from roadlink.simulation.sumo.runner import (
    INSTALL_HINT,
    SumoNotInstalledError,
    SumoRunError,
    find_sumo_home,
    run_sumo,
    sumo_available,
    sumo_home_candidates,
    with_detector_faults,
)
from roadlink.simulation.sumo.scenarios import (
    CAR,
    SUMO_SCENARIOS,
    TRUCK,
    Bottleneck,
    Ramp,
    RoadSegment,
    Signal,
    SumoScenario,
    VehicleClass,
    mix,
    road_segments,
    sensor_ids,
    sumo_scenario,
)

__all__ = [
    "CAR",
    "INSTALL_HINT",
    "MIN_REPORTED_SPEED",
    "SUMO_SCENARIOS",
    "TRUCK",
    "Bottleneck",
    "DetectorFaults",
    "Ramp",
    "RoadSegment",
    "Signal",
    "SumoNotInstalledError",
    "SumoRunError",
    "SumoScenario",
    "VehicleClass",
    "connections_xml",
    "detectors_xml",
    "find_sumo_home",
    "lane_starts",
    "mix",
    "network_xml",
    "parse_detector_output",
    "road_segments",
    "routes_xml",
    "run_sumo",
    "sensor_ids",
    "signals_xml",
    "sumo_available",
    "sumo_home_candidates",
    "sumo_scenario",
    "with_detector_faults",
]
