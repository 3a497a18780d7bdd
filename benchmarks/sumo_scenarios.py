"""The SUMO scenarios benchmarks/sumo_accuracy.py runs beyond the simulator's own
(`roadlink.simulation.sumo.SUMO_SCENARIOS`, the "main" group): validation variants, speed-noise
variants and the holdout queues and arterial, by group."""

from __future__ import annotations

import numpy as np

from roadlink.simulation.sumo import (
    SUMO_SCENARIOS,
    Bottleneck,
    DetectorFaults,
    Ramp,
    Signal,
    SumoScenario,
    mix,
    sumo_scenario,
)


def _spaced(first: float, gaps: list[int]) -> list[float]:
    return [first + float(g) for g in np.cumsum([0, *gaps])]


VALIDATION: dict[str, SumoScenario] = {
    "val-urban": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes at 50 km/h, 1200 veh/h, 11 sensors every 100 m.",
        lanes=2,
        speed_limit=13.89,
        demand=1200.0,
        road_length=1500.0,
        sensor_positions=[100.0 + 100.0 * i for i in range(11)],
    ),
    "val-medium": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h, 12 sensors every 150 m.",
        demand=3000.0,
        sensor_positions=[200.0 + 150.0 * i for i in range(12)],
    ),
    "val-slowzone": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 2500 veh/h, 50 km/h limit at 1.2-1.8 km (no lane drop).",
        demand=2500.0,
        bottleneck=Bottleneck(start=1200.0, end=1800.0, speed_limit=13.9),
        warmup=300.0,
    ),
    "val-wide": sumo_scenario(
        "sumo-freeflow",
        description="4 lanes, 6000 veh/h, 11 sensors every 400 m on a 5 km road.",
        lanes=4,
        demand=6000.0,
        road_length=5000.0,
        sensor_positions=[300.0 + 400.0 * i for i in range(11)],
        duration=120.0,
        warmup=300.0,
    ),
    "val-trucks-faulty": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 2000 veh/h, half trucks; 3% missed, 2% false alarms, 1% speed error.",
        demand=2000.0,
        vehicles=mix(car=0.5, truck=0.5),
        faults=DetectorFaults(miss_probability=0.03, false_alarm_rate=0.02, velocity_noise=0.01),
    ),
    "val-queue-irregular": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h, sensors 60-600 m apart, a lane drop to 1 lane at "
        "2.9-3.4 km, beyond the last sensor: a queue over irregularly spaced sensors.",
        demand=3000.0,
        sensor_positions=_spaced(150.0, [60, 600, 250, 90, 400, 180, 520, 120, 300]),
        bottleneck=Bottleneck(start=2900.0, end=3400.0, lanes=1, speed_limit=11.0),
        road_length=3800.0,
        warmup=900.0,
        duration=300.0,
    ),
    "val-congestion": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 1800 veh/h through a slow zone limited to 8 m/s at 0.8-2.0 km.",
        lanes=2,
        demand=1800.0,
        bottleneck=Bottleneck(start=800.0, end=2000.0, speed_limit=8.0),
        warmup=400.0,
        duration=300.0,
    ),
    "val-lanedrop": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes dropping to 2 at 2.0-2.6 km, 3600 veh/h.",
        demand=3600.0,
        bottleneck=Bottleneck(start=2000.0, end=2600.0, lanes=2),
        warmup=400.0,
    ),
    # Queues and noisy speeds kept apart while the lane anchors' chains learned their smoothness
    # and margins (2026-11-26): never tuned on.
    "val-stopgo3": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3600 veh/h into a 1.2 km zone limited to 5 m/s (1.3-2.5 km).",
        demand=3600.0,
        bottleneck=Bottleneck(start=1300.0, end=2500.0, speed_limit=5.0),
        warmup=600.0,
        duration=300.0,
    ),
    "val-lanedrop2": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2000 veh/h, dropping to 1 lane at 15 m/s at 2.3-2.8 km, sensors "
        "150-700 m apart.",
        lanes=2,
        demand=2000.0,
        bottleneck=Bottleneck(start=2300.0, end=2800.0, lanes=1, speed_limit=15.0),
        sensor_positions=[
            150.0,
            350.0,
            700.0,
            900.0,
            1250.0,
            1400.0,
            1700.0,
            2000.0,
            2200.0,
            2900.0,
        ],
        road_length=3200.0,
        warmup=700.0,
        duration=300.0,
    ),
    "val-creep": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h crawling through a zone limited to 2.5 m/s "
        "(1.5-2.3 km), 12 sensors every 200 m, a 240 s window.",
        demand=3000.0,
        bottleneck=Bottleneck(start=1500.0, end=2300.0, speed_limit=2.5),
        sensor_positions=[200.0 + 200.0 * i for i in range(12)],
        warmup=500.0,
        duration=240.0,
    ),
    "val-dense-noise8": sumo_scenario(
        "sumo-dense",
        description="sumo-dense with speeds measured with an 8 % error.",
        faults=DetectorFaults(velocity_noise=0.08),
    ),
    "val-crawl2": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2200 veh/h into a 1.2 km zone limited to 3 m/s, 15 sensors every "
        "150 m.",
        lanes=2,
        demand=2200.0,
        bottleneck=Bottleneck(start=1200.0, end=2400.0, speed_limit=3.0),
        sensor_positions=[150.0 + 150.0 * i for i in range(15)],
        road_length=2800.0,
        warmup=600.0,
        duration=300.0,
    ),
    "val-drop4to2": sumo_scenario(
        "sumo-freeflow",
        description="4 lanes, 4200 veh/h, dropping to 2 lanes at 16 m/s at 2.2-2.7 km.",
        lanes=4,
        demand=4200.0,
        bottleneck=Bottleneck(start=2200.0, end=2700.0, lanes=2, speed_limit=16.0),
        warmup=600.0,
        duration=240.0,
    ),
    "val-wave": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 4000 veh/h, 20 % trucks, into a zone limited to 6 m/s (1.6-2.4 km).",
        demand=4000.0,
        vehicles=mix(car=0.8, truck=0.2),
        bottleneck=Bottleneck(start=1600.0, end=2400.0, speed_limit=6.0),
        warmup=500.0,
        duration=300.0,
    ),
    "val-faulty-queue": sumo_scenario(
        "sumo-stopgo",
        description="sumo-stopgo seen by faulty detectors: 3 % missed, 3 % false alarms, 3 % "
        "speed error.",
        faults=DetectorFaults(miss_probability=0.03, false_alarm_rate=0.03, velocity_noise=0.03),
    ),
    "val-junctions2": sumo_scenario(
        "sumo-junctions",
        description="2 lanes at 100 km/h, 2000 veh/h, sensors every 200 m, past an on-ramp "
        "(500 veh/h at 520 m), an off-ramp (30 % at 1280 m) and another on-ramp (600 veh/h at "
        "1700 m).",
        lanes=2,
        demand=2000.0,
        speed_limit=27.78,
        road_length=2600.0,
        sensor_positions=[150.0 + 200.0 * i for i in range(12)],
        ramps=[
            Ramp(position=520.0, kind="on", demand=500.0),
            Ramp(position=1280.0, kind="off", share=0.3),
            Ramp(position=1700.0, kind="on", demand=600.0),
        ],
    ),
    "val-junctions-dense": sumo_scenario(
        "sumo-junctions",
        description="3 lanes, 3800 veh/h, an on-ramp (900 veh/h at 1070 m) and an off-ramp "
        "(25 % at 1830 m).",
        demand=3800.0,
        duration=120.0,
        ramps=[
            Ramp(position=1070.0, kind="on", demand=900.0),
            Ramp(position=1830.0, kind="off", share=0.25),
        ],
    ),
}

# Queues and faults simulated to judge the method, not to tune it (2026-11-27). The ho-* six were
# used to find what fails (the window's edges, the segments' learning); the h2-* four were not
# looked at until those changes were made. h3-arterial3 (2026-11-28) judges what is done for
# traffic lights (sumo-arterial), and the h5-* two (2026-11-28, session 23) what is done for
# junctions (sumo-junctions). Change no default on their account.
HOLDOUT: dict[str, SumoScenario] = {
    "ho-drop31": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 2800 veh/h into a lane drop to 1 lane at 8 m/s (2.4-2.9 km).",
        demand=2800.0,
        road_length=3400.0,
        bottleneck=Bottleneck(start=2400.0, end=2900.0, lanes=1, speed_limit=8.0),
        sensor_positions=[200.0 + 200.0 * i for i in range(12)],
        warmup=900.0,
        duration=300.0,
    ),
    "ho-stopgo2": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2300 veh/h into a zone limited to 3 m/s (1.5-2.6 km), sensors "
        "every 300 m.",
        lanes=2,
        demand=2300.0,
        bottleneck=Bottleneck(start=1500.0, end=2600.0, speed_limit=3.0),
        sensor_positions=[200.0 + 300.0 * i for i in range(9)],
        warmup=700.0,
        duration=300.0,
    ),
    "ho-irr-drop": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2200 veh/h, 20 % trucks, sensors 60-540 m apart, a lane drop to 1 "
        "lane at 10 m/s (2.6-3.0 km).",
        lanes=2,
        demand=2200.0,
        vehicles=mix(car=0.8, truck=0.2),
        sensor_positions=[100.0, 160.0, 700.0, 900.0, 1300.0, 1380.0, 1900.0, 2200.0, 2500.0],
        bottleneck=Bottleneck(start=2600.0, end=3000.0, lanes=1, speed_limit=10.0),
        road_length=3300.0,
        warmup=800.0,
        duration=300.0,
    ),
    "ho-congestion": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2000 veh/h through a zone limited to 8 m/s (1.0-2.2 km).",
        lanes=2,
        demand=2000.0,
        bottleneck=Bottleneck(start=1000.0, end=2200.0, speed_limit=8.0),
        warmup=500.0,
        duration=270.0,
    ),
    "ho-dense4-noise6": sumo_scenario(
        "sumo-freeflow",
        description="4 lanes, 5500 veh/h, speeds read with a 6 % error.",
        lanes=4,
        demand=5500.0,
        duration=120.0,
        faults=DetectorFaults(velocity_noise=0.06),
    ),
    "ho-urban-faulty": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes at 50 km/h, 1400 veh/h, 30 % trucks, sensors every 120 m; 4 % "
        "missed, 3 % false alarms, 4 % speed error.",
        lanes=2,
        speed_limit=13.89,
        demand=1400.0,
        road_length=1400.0,
        sensor_positions=[100.0 + 120.0 * i for i in range(10)],
        vehicles=mix(car=0.7, truck=0.3),
        faults=DetectorFaults(miss_probability=0.04, false_alarm_rate=0.03, velocity_noise=0.04),
    ),
    "h2-drop21": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2100 veh/h into a lane drop to 1 lane at 6 m/s (2.1-2.6 km).",
        lanes=2,
        demand=2100.0,
        road_length=3000.0,
        bottleneck=Bottleneck(start=2100.0, end=2600.0, lanes=1, speed_limit=6.0),
        sensor_positions=[150.0 + 250.0 * i for i in range(9)],
        warmup=800.0,
        duration=300.0,
    ),
    "h2-stopgo3l": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3300 veh/h into a zone limited to 3.5 m/s (1.7-2.5 km), sensors "
        "every 220 m.",
        demand=3300.0,
        bottleneck=Bottleneck(start=1700.0, end=2500.0, speed_limit=3.5),
        sensor_positions=[250.0 + 220.0 * i for i in range(11)],
        warmup=700.0,
        duration=300.0,
    ),
    "h2-slow-trucks": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 1800 veh/h, 40 % trucks, through a zone limited to 7 m/s "
        "(1.2-2.0 km).",
        lanes=2,
        demand=1800.0,
        vehicles=mix(car=0.6, truck=0.4),
        bottleneck=Bottleneck(start=1200.0, end=2000.0, speed_limit=7.0),
        warmup=500.0,
        duration=300.0,
    ),
    "h2-faulty-crawl": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2000 veh/h crawling through a zone limited to 2.5 m/s (1.0-2.2 "
        "km), sensors every 180 m; 4 % missed, 3 % false alarms, 5 % speed error.",
        lanes=2,
        demand=2000.0,
        bottleneck=Bottleneck(start=1000.0, end=2200.0, speed_limit=2.5),
        sensor_positions=[150.0 + 180.0 * i for i in range(12)],
        road_length=2700.0,
        warmup=600.0,
        duration=300.0,
        faults=DetectorFaults(miss_probability=0.04, false_alarm_rate=0.03, velocity_noise=0.05),
    ),
    "h4-urban-bias": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes at 50 km/h, 2400 veh/h, sensors 80-200 m apart, each loop's speeds "
        "off by a factor of its own (8 %, lognormal) and read with a 4 % error.",
        lanes=2,
        speed_limit=13.89,
        demand=2400.0,
        road_length=1500.0,
        sensor_positions=_spaced(100.0, [80, 200, 120, 150, 90, 180, 110, 160, 130]),
        faults=DetectorFaults(velocity_bias=0.08, velocity_noise=0.04),
    ),
    "h3-arterial3": sumo_scenario(
        "sumo-arterial",
        description="3 lanes at 60 km/h, 1800 veh/h, 20 % trucks, sensors every 120 m, through "
        "three fixed-time traffic lights of different cycles (60-78 s).",
        lanes=3,
        speed_limit=16.67,
        demand=1800.0,
        vehicles=mix(car=0.8, truck=0.2),
        road_length=1800.0,
        sensor_positions=[80.0 + 120.0 * i for i in range(14)],
        signals=[
            Signal(position=450.0, green=30.0, red=30.0),
            Signal(position=1010.0, green=45.0, red=30.0, offset=35.0),
            Signal(position=1500.0, green=35.0, red=40.0, offset=10.0),
        ],
        warmup=400.0,
    ),
    "h5-interchange": sumo_scenario(
        "sumo-junctions",
        description="3 lanes at 110 km/h, 3600 veh/h, 15 % trucks, sensors every 400 m: an "
        "interchange whose off-ramp (25 %) and on-ramp (800 veh/h) both lie between two sensors, "
        "and a later on-ramp (400 veh/h); speeds read with a 3 % error.",
        speed_limit=30.56,
        demand=3600.0,
        vehicles=mix(car=0.85, truck=0.15),
        road_length=4600.0,
        sensor_positions=[300.0 + 400.0 * i for i in range(11)],
        ramps=[
            Ramp(position=1380.0, kind="off", share=0.25),
            Ramp(position=1700.0, kind="on", demand=800.0),
            Ramp(position=3050.0, kind="on", demand=400.0),
        ],
        faults=DetectorFaults(velocity_noise=0.03),
    ),
    "h5-ring-road": sumo_scenario(
        "sumo-junctions",
        description="2 lanes at 80 km/h, 2400 veh/h, sensors 150-350 m apart, five junctions "
        "close together (on, off, on, off, on): a city ring road, 3 % of detections missed.",
        lanes=2,
        speed_limit=22.22,
        demand=2400.0,
        road_length=3000.0,
        sensor_positions=_spaced(150.0, [250, 150, 350, 200, 300, 180, 270, 220, 320, 160]),
        ramps=[
            Ramp(position=480.0, kind="on", demand=400.0),
            Ramp(position=1000.0, kind="off", share=0.2),
            Ramp(position=1230.0, kind="on", demand=500.0),
            Ramp(position=2020.0, kind="off", share=0.25),
            Ramp(position=2270.0, kind="on", demand=300.0),
        ],
        faults=DetectorFaults(miss_probability=0.03),
    ),
}


# Loops measure speed with an error: a dual loop times the vehicle between its two loops (a few
# per cent), a single loop infers speed from occupancy and an assumed vehicle length (far more),
# and that length, set per loop, makes each loop's speeds off by a factor of its own (`-bias`).
SPEED_NOISE: dict[str, SumoScenario] = {
    **{
        f"{base}-speed{round(100 * noise)}": sumo_scenario(
            base,
            description=f"{base}, speeds measured with a {noise:.0%} error (std), no other fault.",
            faults=DetectorFaults(velocity_noise=noise),
        )
        for base in ("sumo-freeflow", "sumo-dense")
        for noise in (0.03, 0.06, 0.10)
    },
    **{
        f"{base}-bias10": sumo_scenario(
            base,
            description=f"{base}, each sensor's speeds off by a factor of its own (lognormal, "
            "10 % std), no other fault.",
            faults=DetectorFaults(velocity_bias=0.1),
        )
        for base in ("sumo-freeflow", "sumo-dense", "sumo-irregular")
    },
}
SCENARIO_GROUPS = {
    "main": SUMO_SCENARIOS,
    "validation": VALIDATION,
    "speed-noise": SPEED_NOISE,
    "holdout": HOLDOUT,
}
EVERY_SCENARIO = {name: case for group in SCENARIO_GROUPS.values() for name, case in group.items()}
