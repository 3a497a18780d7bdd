"""What a SUMO run simulates: a straight road, its sensors, its traffic and its detectors' faults,
and the named scenarios the benchmarks and tests use."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from itertools import pairwise
from typing import Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from roadlink.simulation.faults import DetectorFaults


class VehicleClass(BaseModel):
    """One kind of vehicle in the traffic mix."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_]*$", description="vType id; labels start so.")
    share: float = Field(gt=0, le=1, description="Share of the demand.")
    vclass: str = Field(default="passenger", description="SUMO vehicle class.")
    length: float = Field(default=4.5, gt=0, description="Length (m).")
    length_range: tuple[float, float] | None = Field(
        default=None,
        description="Where the scenario's detectors report features: the vehicles' lengths "
        "spread evenly over this range (m), instead of all being `length`.",
    )
    max_speed: float = Field(default=50.0, gt=0, description="Top speed of the vehicle (m/s).")
    speed_factor: float = Field(
        default=1.0, gt=0, description="Mean desired speed as a share of the speed limit."
    )
    speed_deviation: float = Field(
        default=0.1, ge=0, le=1, description="Spread (std) of the desired-speed factor."
    )
    accel: float = Field(default=2.6, gt=0, description="Maximum acceleration (m/s^2).")
    decel: float = Field(default=4.5, gt=0, description="Comfortable deceleration (m/s^2).")
    sigma: float = Field(
        default=0.5, ge=0, le=1, description="Krauss driver imperfection (random slowing)."
    )


CAR = VehicleClass(
    name="car", share=1.0, length_range=(3.6, 5.4), max_speed=50.0, speed_deviation=0.12
)
VAN = VehicleClass(
    name="van",
    share=1.0,
    vclass="delivery",
    length=6.0,
    length_range=(5.0, 7.0),
    max_speed=44.0,
    speed_factor=0.95,
    speed_deviation=0.1,
    accel=2.0,
)
TRUCK = VehicleClass(
    name="truck",
    share=1.0,
    vclass="truck",
    length=12.0,
    length_range=(8.0, 18.0),
    # Speed limiters hold trucks near 90 km/h, each a little differently.
    max_speed=26.4,
    speed_factor=0.75,
    speed_deviation=0.05,
    accel=1.0,
    decel=4.0,
)


def mix(**shares: float) -> list[VehicleClass]:
    """The standard classes (car, van, truck) in the given shares: ``mix(car=0.9, truck=0.1)``."""
    known = {"car": CAR, "van": VAN, "truck": TRUCK}
    return [known[name].model_copy(update={"share": share}) for name, share in shares.items()]


class Bottleneck(BaseModel):
    """A stretch with fewer lanes (a lane drop, as at roadworks) and/or a lower speed limit."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    start: float = Field(ge=0, description="Where it begins (m from the road's start).")
    end: float = Field(description="Where it ends (m).")
    lanes: int | None = Field(default=None, ge=1, description="Lanes in it (None: unchanged).")
    speed_limit: float | None = Field(
        default=None, gt=0, description="Speed limit in it (m/s; None: unchanged)."
    )

    @model_validator(mode="after")
    def _ordered(self) -> Bottleneck:
        if self.end <= self.start:
            raise ValueError("bottleneck end must be beyond its start")
        if self.lanes is None and self.speed_limit is None:
            raise ValueError("a bottleneck needs fewer lanes or a lower speed limit")
        return self


class Signal(BaseModel):
    """A fixed-time traffic light across the road: green, then YELLOW seconds of amber, then red,
    over and over (the cycle starts `offset` seconds into the simulation)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(gt=0, description="Where it stands (m from the road's start).")
    green: float = Field(default=40.0, gt=0, description="Green time (s).")
    red: float = Field(default=35.0, gt=0, description="Red time (s).")
    offset: float = Field(default=0.0, ge=0, description="Seconds into the first cycle at 0.")


# Amber between green and red (s), as at urban signals.
YELLOW = 3.0


class Ramp(BaseModel):
    """A junction's slip road: an on-ramp where vehicles join the road, or an off-ramp where some
    leave it. No sensor stands on a ramp, so a vehicle that joins is first seen downstream of it
    and one that leaves is seen last upstream of it."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    position: float = Field(gt=0, description="Where the ramp meets the road (m from its start).")
    kind: Literal["on", "off"] = Field(description="'on': vehicles join; 'off': some leave.")
    demand: float = Field(
        default=600.0,
        gt=0,
        le=5000,
        description="An on-ramp's traffic (vehicles per hour, in the road's mix of classes).",
    )
    share: float = Field(
        default=0.15,
        gt=0,
        lt=1,
        description="The share of the vehicles reaching an off-ramp that take it.",
    )

    @property
    def added_lane(self) -> tuple[float, float]:
        """Where the lane the ramp adds to the road begins and ends (m): an on-ramp's
        acceleration lane after it, an off-ramp's deceleration lane before it."""
        if self.kind == "on":
            return (self.position, self.position + ACCELERATION_LANE)
        return (self.position - DECELERATION_LANE, self.position)


# The lane a ramp adds to the road (m): vehicles joining merge over the first, vehicles
# leaving move onto the second before the ramp.
ACCELERATION_LANE = 250.0
DECELERATION_LANE = 150.0


class SumoScenario(BaseModel):
    """A straight road, its sensors, its traffic, and what the detectors get wrong."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    description: str = Field(default="", description="What the scenario models.")
    road_length: float = Field(default=3000.0, gt=0, le=50_000, description="Road length (m).")
    lanes: int = Field(default=3, ge=1, le=6, description="Lanes of the road.")
    speed_limit: float = Field(default=33.33, gt=0, description="Speed limit (m/s).")
    sensor_positions: list[float] = Field(
        default=[200.0 + 250.0 * i for i in range(11)],
        min_length=2,
        description="Sensor positions along the road (m).",
    )
    demand: float = Field(default=1500.0, gt=0, le=20_000, description="Vehicles per hour.")
    vehicles: list[VehicleClass] = Field(
        default_factory=lambda: mix(car=0.9, truck=0.1), min_length=1
    )
    bottleneck: Bottleneck | None = None
    signals: list[Signal] = Field(
        default_factory=list, description="Traffic lights across the road (an arterial)."
    )
    ramps: list[Ramp] = Field(
        default_factory=list, description="Slip roads where vehicles join or leave the road."
    )
    warmup: float = Field(
        default=200.0, ge=0, description="Simulated time before detections are kept (s)."
    )
    duration: float = Field(
        default=240.0, gt=0, le=7200, description="Length of the kept time window (s)."
    )
    step_length: float = Field(default=0.5, gt=0, le=1, description="SUMO time step (s).")
    faults: DetectorFaults = Field(default_factory=DetectorFaults)
    features: bool = Field(
        default=False,
        description="Detectors report each vehicle's lane (SUMO's lane index, 0 = rightmost), "
        "length (measured with `faults.length_noise`) and class (its vehicle class's name); "
        "vehicles' lengths then spread over their class's `length_range`.",
    )

    @model_validator(mode="after")
    def _consistent(self) -> SumoScenario:
        positions = self.sensor_positions
        if len(set(positions)) != len(positions):
            raise ValueError("sensor_positions must be distinct")
        if min(positions) <= 0 or max(positions) >= self.road_length:
            raise ValueError("sensor_positions must lie strictly inside the road")
        if self.bottleneck is not None and self.bottleneck.end >= self.road_length:
            raise ValueError("the bottleneck must end before the road does")
        at = [signal.position for signal in self.signals]
        if len(set(at)) != len(at) or any(x >= self.road_length for x in at):
            raise ValueError("signals must stand at distinct positions inside the road")
        if set(at) & set(positions):
            raise ValueError("a signal cannot stand where a sensor does")
        self._ramps_clear(positions, at)
        return self

    def _ramps_clear(self, sensors: list[float], signals: list[float]) -> None:
        """Each ramp's added lane lies inside the road, clear of the other ramps' lanes, the
        signals and the bottleneck's ends, and no sensor stands where a ramp meets the road."""
        stretches = sorted(ramp.added_lane for ramp in self.ramps)
        if stretches and (stretches[0][0] <= 0 or stretches[-1][1] >= self.road_length):
            raise ValueError("a ramp and the lane it adds must lie inside the road")
        if any(b[0] <= a[1] for a, b in pairwise(stretches)):
            raise ValueError("ramps' added lanes must not overlap")
        neck = self.bottleneck
        others = signals + ([neck.start, neck.end] if neck is not None else [])
        if any(a <= x <= b for a, b in stretches for x in others):
            raise ValueError("a ramp's added lane must keep clear of signals and bottlenecks")
        if {r.position for r in self.ramps} & set(sensors):
            raise ValueError("a ramp cannot meet the road where a sensor stands")


def _spaced(first: float, gaps: Sequence[float]) -> list[float]:
    return [first + float(g) for g in np.cumsum([0.0, *gaps])]


SUMO_SCENARIOS: dict[str, SumoScenario] = {
    "sumo-freeflow": SumoScenario(
        description="3 lanes, 1500 veh/h, 10% trucks: free flow with overtaking on every lane.",
        demand=1500.0,
    ),
    "sumo-dense": SumoScenario(
        description="3 lanes, 4500 veh/h, 10% trucks: dense but flowing traffic, short headways "
        "and many lane changes.",
        demand=4500.0,
        duration=120.0,
    ),
    "sumo-bottleneck": SumoScenario(
        description="3 lanes, 2400 veh/h into a lane drop to 1 lane at 80 km/h (roadworks at "
        "2.0-2.6 km): a queue grows back from the drop past the middle sensors, with "
        "stop-and-go waves (speeds near 0) inside it and free flow upstream of its tail.",
        demand=2400.0,
        bottleneck=Bottleneck(start=2000.0, end=2600.0, lanes=1, speed_limit=22.22),
        warmup=400.0,
        duration=240.0,
    ),
    "sumo-irregular": SumoScenario(
        description="2 lanes, 2000 veh/h, 30% trucks, irregular sensor spacing (30 m to 700 m).",
        lanes=2,
        demand=2000.0,
        vehicles=mix(car=0.7, truck=0.3),
        sensor_positions=_spaced(150.0, [30, 420, 700, 60, 260, 540, 35, 380, 90]),
    ),
    "sumo-queue": SumoScenario(
        description="3 lanes, 3000 veh/h into a lane drop to 1 lane at 30 km/h (2.0-2.6 km), "
        "after a 15-minute warm-up: the queue reaches back past most sensors, vehicles crawl "
        "and stop in it, and the last sensor sees them leave.",
        demand=3000.0,
        bottleneck=Bottleneck(start=2000.0, end=2600.0, lanes=1, speed_limit=8.33),
        warmup=900.0,
        duration=300.0,
    ),
    "sumo-stopgo": SumoScenario(
        description="2 lanes, 2400 veh/h into a 1.2 km zone limited to 4 m/s (1.1-2.3 km): "
        "the queue it causes reaches back past most sensors: eight see stop-and-go at 2-3 m/s.",
        lanes=2,
        demand=2400.0,
        bottleneck=Bottleneck(start=1100.0, end=2300.0, speed_limit=4.0),
        warmup=500.0,
        duration=300.0,
    ),
    "sumo-arterial": SumoScenario(
        description="2 lanes at 50 km/h, 1200 veh/h, 10% trucks, sensors every 150 m, through "
        "two fixed-time traffic lights (40 s green, 3 s amber, 35 s red; the second 20 s later): "
        "one mid-segment, one 20 m past a sensor, whose queue reaches back over it.",
        lanes=2,
        speed_limit=13.89,
        demand=1200.0,
        road_length=2000.0,
        sensor_positions=[100.0 + 150.0 * i for i in range(12)],
        signals=[Signal(position=640.0), Signal(position=1320.0, offset=20.0)],
        warmup=300.0,
        duration=300.0,
    ),
    "sumo-junctions": SumoScenario(
        description="3 lanes, 3000 veh/h, 10% trucks, past two junctions between sensors: at "
        "each, an off-ramp takes a share of the traffic (20 % at 830 m, 15 % at 1830 m) and an "
        "on-ramp brings more (700 veh/h at 1070 m, 500 at 2080 m), merging from an acceleration "
        "lane: vehicles leave and join the road where no sensor sees them.",
        demand=3000.0,
        ramps=[
            Ramp(position=830.0, kind="off", share=0.2),
            Ramp(position=1070.0, kind="on", demand=700.0),
            Ramp(position=1830.0, kind="off", share=0.15),
            Ramp(position=2080.0, kind="on", demand=500.0),
        ],
    ),
    "sumo-faulty": SumoScenario(
        description="sumo-dense seen by faulty detectors: 5% missed, 5% false alarms, 2% "
        "duplicated, speed error 3%, timestamp error 0.05 s.",
        demand=4500.0,
        duration=120.0,
        faults=DetectorFaults(
            miss_probability=0.05,
            false_alarm_rate=0.05,
            duplicate_probability=0.02,
            velocity_noise=0.03,
            timestamp_noise=0.05,
        ),
    ),
}


def sumo_scenario(name: str, **overrides: object) -> SumoScenario:
    """A named scenario with some settings changed (validated again)."""
    try:
        base = SUMO_SCENARIOS[name]
    except KeyError:
        known = ", ".join(SUMO_SCENARIOS)
        raise ValueError(f"unknown SUMO scenario '{name}'; known: {known}") from None
    return SumoScenario.model_validate({**base.model_dump(), **overrides})


def sensor_ids(scenario: SumoScenario) -> dict[str, float]:
    """Sensor id -> position, named S1, S2, ... in road order (as the simulator names them)."""
    return {f"S{k + 1}": p for k, p in enumerate(sorted(scenario.sensor_positions))}


@dataclass(frozen=True)
class RoadSegment:
    """One SUMO edge of the road: a stretch with a constant lane count and speed limit."""

    edge: str
    start: float
    end: float
    lanes: int
    speed_limit: float


def road_segments(scenario: SumoScenario) -> list[RoadSegment]:
    """The road cut into edges where the lane count or the speed limit changes, and at each
    signal and ramp (each stands at a junction between two edges)."""
    neck = scenario.bottleneck
    normal = (scenario.lanes, scenario.speed_limit)
    if neck is None:
        stretches = [(0.0, scenario.road_length, *normal)]
    else:
        narrow = (neck.lanes or scenario.lanes, neck.speed_limit or scenario.speed_limit)
        stretches = [
            (0.0, neck.start, *normal),
            (neck.start, neck.end, *narrow),
            (neck.end, scenario.road_length, *normal),
        ]
    junctions = {signal.position for signal in scenario.signals}
    added = [ramp.added_lane for ramp in scenario.ramps]
    junctions |= {x for lane in added for x in lane}
    for x in sorted(junctions):
        stretches = [
            part
            for start, end, lanes, speed in stretches
            for part in (
                [(start, x, lanes, speed), (x, end, lanes, speed)]
                if start < x < end
                else [(start, end, lanes, speed)]
            )
        ]
    stretches = [
        (start, end, lanes + any(a <= start and end <= b for a, b in added), speed)
        for start, end, lanes, speed in stretches
    ]
    kept = [s for s in stretches if s[1] > s[0]]  # a bottleneck may start at 0
    return [RoadSegment(f"e{k}", *stretch) for k, stretch in enumerate(kept)]
