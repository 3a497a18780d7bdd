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
the parsed detections afterwards, with their own seeded random generator.

This module imports without SUMO; only `run_sumo` needs it (PyPI `eclipse-sumo`, the optional extra
`roadlink[sumo]`). Everything that turns a scenario into SUMO's input files, and SUMO's detector
output into `Detections`, is plain Python and tested without SUMO.
"""

from __future__ import annotations

import importlib.util
import math
import os
import shutil
import subprocess
import tempfile
import xml.etree.ElementTree as ET
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from roadlink.association.detections import CLUTTER, Detections

INSTALL_HINT = "pip install 'roadlink[sumo]'"

# A loop reports the speed of a vehicle crawling over it as small but positive (its speed comes
# from the time the vehicle occupies it); SUMO may report exactly 0 for a vehicle that stopped
# within the step it entered, which no real detector reports and `Detections` rejects.
MIN_REPORTED_SPEED = 0.1

# Detectors stay this far from an edge's ends, where SUMO's junction lanes begin.
EDGE_MARGIN = 0.5


class SumoNotInstalledError(RuntimeError):
    """The SUMO binaries are not found."""


class SumoRunError(RuntimeError):
    """A SUMO tool failed; the message carries its error output."""


class VehicleClass(BaseModel):
    """One kind of vehicle in the traffic mix."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    name: str = Field(pattern=r"^[A-Za-z][A-Za-z0-9_]*$", description="vType id; labels start so.")
    share: float = Field(gt=0, le=1, description="Share of the demand.")
    vclass: str = Field(default="passenger", description="SUMO vehicle class.")
    length: float = Field(default=4.5, gt=0, description="Length (m).")
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


CAR = VehicleClass(name="car", share=1.0, max_speed=50.0, speed_deviation=0.12)
TRUCK = VehicleClass(
    name="truck",
    share=1.0,
    vclass="truck",
    length=12.0,
    # Speed limiters hold trucks near 90 km/h, each a little differently.
    max_speed=26.4,
    speed_factor=0.75,
    speed_deviation=0.05,
    accel=1.0,
    decel=4.0,
)


def mix(**shares: float) -> list[VehicleClass]:
    """The standard car and truck classes in the given shares, e.g. ``mix(car=0.9, truck=0.1)``."""
    known = {"car": CAR, "truck": TRUCK}
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


class DetectorFaults(BaseModel):
    """What real loop detectors get wrong, applied after the simulation."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    miss_probability: float = Field(default=0.0, ge=0, lt=1, description="Chance of a miss.")
    false_alarm_rate: float = Field(
        default=0.0, ge=0, le=10, description="False alarms per sensor, per true detection."
    )
    duplicate_probability: float = Field(
        default=0.0, ge=0, lt=1, description="Chance that a passage is reported twice."
    )
    velocity_noise: float = Field(
        default=0.0, ge=0, le=1, description="Speed measurement error (std, share of speed)."
    )
    timestamp_noise: float = Field(
        default=0.0, ge=0, description="Timestamp measurement error (std, seconds)."
    )


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
    warmup: float = Field(
        default=200.0, ge=0, description="Simulated time before detections are kept (s)."
    )
    duration: float = Field(
        default=240.0, gt=0, le=7200, description="Length of the kept time window (s)."
    )
    step_length: float = Field(default=0.5, gt=0, le=1, description="SUMO time step (s).")
    faults: DetectorFaults = Field(default_factory=DetectorFaults)

    @model_validator(mode="after")
    def _consistent(self) -> SumoScenario:
        positions = self.sensor_positions
        if len(set(positions)) != len(positions):
            raise ValueError("sensor_positions must be distinct")
        if min(positions) <= 0 or max(positions) >= self.road_length:
            raise ValueError("sensor_positions must lie strictly inside the road")
        if self.bottleneck is not None and self.bottleneck.end >= self.road_length:
            raise ValueError("the bottleneck must end before the road does")
        return self


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
    """The road cut into edges where the lane count or the speed limit changes."""
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
    kept = [s for s in stretches if s[1] > s[0]]  # a bottleneck may start at 0
    return [RoadSegment(f"e{k}", *stretch) for k, stretch in enumerate(kept)]


def network_xml(scenario: SumoScenario) -> tuple[str, str]:
    """Plain nodes and edges XML of the road (for netconvert); the road runs along x from 0."""
    segments = road_segments(scenario)
    xs = [segments[0].start] + [s.end for s in segments]
    nodes = "".join(f'  <node id="n{k}" x="{x:.2f}" y="0.00"/>\n' for k, x in enumerate(xs))
    edges = "".join(
        f'  <edge id="{s.edge}" from="n{k}" to="n{k + 1}" numLanes="{s.lanes}" '
        f'speed="{s.speed_limit:.2f}"/>\n'
        for k, s in enumerate(segments)
    )
    return f"<nodes>\n{nodes}</nodes>\n", f"<edges>\n{edges}</edges>\n"


def routes_xml(scenario: SumoScenario) -> str:
    """Vehicle types and one Poisson flow per type over the whole road."""
    segments = road_segments(scenario)
    total = sum(v.share for v in scenario.vehicles)
    end = scenario.warmup + scenario.duration
    lines = ["<routes>"]
    for v in scenario.vehicles:
        # Desired-speed factors are normal, cut at +-3 std (and kept positive).
        dev = v.speed_deviation
        low, high = max(0.2, v.speed_factor - 3 * dev), v.speed_factor + 3 * dev
        lines.append(
            f'  <vType id="{v.name}" vClass="{v.vclass}" length="{v.length}" '
            f'maxSpeed="{v.max_speed}" accel="{v.accel}" decel="{v.decel}" sigma="{v.sigma}" '
            f'speedFactor="normc({v.speed_factor},{dev},{low:.3f},{high:.3f})"/>'
        )
    lines.append(f'  <route id="road" edges="{" ".join(s.edge for s in segments)}"/>')
    for v in scenario.vehicles:
        rate = scenario.demand * v.share / total / 3600.0  # vehicles per second
        lines.append(
            f'  <flow id="{v.name}" type="{v.name}" route="road" begin="0" end="{end}" '
            f'period="exp({rate:.6f})" departLane="free" departSpeed="max"/>'
        )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def lane_starts(net_xml: str) -> dict[str, tuple[float, float]]:
    """Lane id -> (x where the lane starts, its length), read from a netconvert network.

    netconvert shortens edges by their junctions, so a detector's offset on its lane is taken from
    the lane's actual geometry, not from the nominal edge boundaries.
    """
    lanes = {}
    for edge in ET.fromstring(net_xml).iter("edge"):
        if edge.get("function") == "internal":
            continue
        for lane in edge.iter("lane"):
            first = lane.attrib["shape"].split()[0]
            lanes[lane.attrib["id"]] = (float(first.split(",")[0]), float(lane.attrib["length"]))
    return lanes


def detectors_xml(scenario: SumoScenario, net_xml: str, output_file: str) -> str:
    """An instantInductionLoop on every lane at every sensor position (ids ``S3:1``)."""
    lanes = lane_starts(net_xml)
    lines = ["<additional>"]
    for sensor, position in sensor_ids(scenario).items():
        segment = next(
            s for s in road_segments(scenario) if s.start <= position < s.end
        )  # the validator keeps every sensor on the road
        for index in range(segment.lanes):
            lane = f"{segment.edge}_{index}"
            start, length = lanes[lane]
            offset = min(max(position - start, EDGE_MARGIN), length - EDGE_MARGIN)
            lines.append(
                f'  <instantInductionLoop id="{sensor}:{index}" lane="{lane}" '
                f'pos="{offset:.2f}" file="{output_file}"/>'
            )
    lines.append("</additional>")
    return "\n".join(lines) + "\n"


def parse_detector_output(
    xml: str | bytes,
    sensors: Mapping[str, float],
    window: tuple[float, float] | None = None,
) -> Detections:
    """SUMO instantInductionLoop output as labelled detections.

    Detector ids are ``SENSOR:LANE``; `sensors` maps each sensor id to its position. Every
    vehicle's first ``enter`` at a sensor is its detection (a vehicle changing lanes over a sensor
    can enter a second lane's loop; one sensor is all its lanes, so that is not a new passage).
    Only entries with ``window[0] <= time < window[1]`` are kept, their timestamps counted from
    ``window[0]``. The target label is SUMO's vehicle id.
    """
    start, end = window if window is not None else (-math.inf, math.inf)
    first: dict[tuple[str, str], tuple[float, float]] = {}
    for event in ET.fromstring(xml).iter("instantOut"):
        if event.get("state") != "enter":
            continue
        sensor = event.attrib["id"].rsplit(":", 1)[0]
        if sensor not in sensors:
            raise ValueError(f"detector '{event.attrib['id']}' belongs to no known sensor")
        time = float(event.attrib["time"])
        if not start <= time < end:
            continue
        key = (sensor, event.attrib["vehID"])
        if key not in first or time < first[key][0]:
            first[key] = (time, float(event.attrib["speed"]))
    order = sorted(first, key=lambda k: (sensors[k[0]], first[k][0]))
    origin = start if math.isfinite(start) else 0.0
    return Detections.from_columns(
        [sensors[s] for s, _ in order],
        [max(first[k][1], MIN_REPORTED_SPEED) for k in order],
        # SUMO writes times to 0.01 s; rounding drops the float noise of the subtraction.
        [round(first[k][0] - origin, 6) for k in order],
        sensor_id=[s for s, _ in order],
        target=[vehicle for _, vehicle in order],
    )


def apply_detector_faults(
    detections: Detections, faults: DetectorFaults, rng: np.random.Generator
) -> Detections:
    """Misses, duplicates, false alarms and measurement noise, as real loop detectors make them.

    A duplicate is the same passage reported again up to 0.5 s later with a speed 2% off; a false
    alarm (label ``clutter``) comes at a uniformly random time in its sensor's busy period with a
    speed drawn from what that sensor saw, so it looks like any other vehicle. Output is ordered
    by sensor position, then time.
    """
    n = len(detections)
    keep = rng.random(n) >= faults.miss_probability
    position, velocity = detections.position[keep], detections.velocity[keep]
    timestamp, sensor = detections.timestamp[keep], detections.sensor_id[keep]
    target = detections.target[keep]

    twice = np.flatnonzero(rng.random(position.size) < faults.duplicate_probability)
    position = np.concatenate([position, position[twice]])
    sensor = np.concatenate([sensor, sensor[twice]])
    target = np.concatenate([target, target[twice]])
    timestamp = np.concatenate([timestamp, timestamp[twice] + rng.uniform(0, 0.5, twice.size)])
    velocity = np.concatenate(
        [velocity, velocity[twice] * (1.0 + 0.02 * rng.standard_normal(twice.size))]
    )

    if faults.velocity_noise:
        velocity = velocity * np.exp(faults.velocity_noise * rng.standard_normal(velocity.size))
    if faults.timestamp_noise:
        timestamp = timestamp + faults.timestamp_noise * rng.standard_normal(timestamp.size)

    parts = [(position, velocity, timestamp, sensor, target)]
    if faults.false_alarm_rate:
        for where in np.unique(position):
            at = position == where
            count = rng.poisson(faults.false_alarm_rate * int(at.sum()))
            seen_time, seen_speed = timestamp[at], velocity[at]
            parts.append(
                (
                    np.full(count, where),
                    rng.choice(seen_speed, count) * np.exp(0.05 * rng.standard_normal(count)),
                    rng.uniform(seen_time.min(), seen_time.max(), count),
                    np.full(count, sensor[at][0], dtype=object),
                    np.full(count, CLUTTER, dtype=object),
                )
            )
    position, velocity, timestamp, sensor, target = (
        np.concatenate(c) for c in zip(*parts, strict=True)
    )
    velocity = np.maximum(velocity, MIN_REPORTED_SPEED)
    order = np.lexsort((timestamp, position))
    return Detections.from_columns(
        position[order],
        velocity[order],
        timestamp[order],
        sensor_id=sensor[order].tolist(),
        target=target[order].tolist(),
    )


def sumo_home_candidates() -> list[Path]:
    """Where SUMO may live, in order: the `eclipse-sumo` package, $SUMO_HOME, `sumo` on the PATH."""
    candidates: list[Path] = []
    # find_spec, not import: importing the package would set SUMO_HOME in our environment.
    spec = importlib.util.find_spec("sumo")
    if spec is not None and spec.submodule_search_locations:
        candidates.extend(Path(p) for p in spec.submodule_search_locations)
    if os.environ.get("SUMO_HOME"):
        candidates.append(Path(os.environ["SUMO_HOME"]))
    on_path = shutil.which("sumo")
    if on_path:
        candidates.append(Path(on_path).resolve().parent.parent)
    return candidates


def find_sumo_home() -> Path:
    """The first SUMO installation with the binaries `run_sumo` needs.

    Raises SumoNotInstalledError, saying how to install it, when there is none.
    """
    for home in sumo_home_candidates():
        if (home / "bin" / "sumo").is_file() and (home / "bin" / "netconvert").is_file():
            return home
    raise SumoNotInstalledError(
        f"Eclipse SUMO is not installed: {INSTALL_HINT} (or set SUMO_HOME to a SUMO installation)"
    )


def sumo_available() -> bool:
    """True when `run_sumo` can find SUMO."""
    try:
        find_sumo_home()
    except SumoNotInstalledError:
        return False
    return True


def run_sumo(scenario: SumoScenario, seed: int = 0, workdir: Path | None = None) -> Detections:
    """Simulate the scenario with SUMO and return what its sensors detected, faults applied.

    The same scenario and seed give the same detections. SUMO's files (network, routes,
    detectors, output) are written to `workdir` when given (to inspect them), else to a
    temporary directory that is removed afterwards.
    """
    home = find_sumo_home()
    if workdir is not None:
        workdir.mkdir(parents=True, exist_ok=True)
        return _run_in(home, scenario, seed, workdir)
    with tempfile.TemporaryDirectory(prefix="roadlink-sumo-") as tmp:
        return _run_in(home, scenario, seed, Path(tmp))


def _run_in(home: Path, scenario: SumoScenario, seed: int, work: Path) -> Detections:
    nodes, edges = network_xml(scenario)
    (work / "road.nod.xml").write_text(nodes)
    (work / "road.edg.xml").write_text(edges)
    (work / "road.rou.xml").write_text(routes_xml(scenario))
    _call(
        home, "netconvert", work, "-n", "road.nod.xml", "-e", "road.edg.xml", "-o", "road.net.xml"
    )
    net = (work / "road.net.xml").read_text()
    (work / "detectors.add.xml").write_text(detectors_xml(scenario, net, "detections.xml"))
    _call(
        home,
        "sumo",
        work,
        *("-n", "road.net.xml", "-r", "road.rou.xml", "-a", "detectors.add.xml"),
        *("--begin", "0", "--end", f"{scenario.warmup + scenario.duration}"),
        *("--step-length", f"{scenario.step_length}", "--seed", str(seed)),
        *("--no-step-log", "--duration-log.disable", "--no-warnings"),
    )
    detections = parse_detector_output(
        (work / "detections.xml").read_bytes(),
        sensor_ids(scenario),
        (scenario.warmup, scenario.warmup + scenario.duration),
    )
    if scenario.faults != DetectorFaults():
        # Its own stream, so faults never change what SUMO simulated.
        rng = np.random.default_rng([seed, 0x5E45])
        detections = apply_detector_faults(detections, scenario.faults, rng)
    return detections


def _call(home: Path, tool: str, work: Path, *args: str) -> None:
    env = {**os.environ, "SUMO_HOME": str(home)}
    done = subprocess.run(
        [str(home / "bin" / tool), *args], cwd=work, env=env, capture_output=True, text=True
    )
    if done.returncode != 0:
        raise SumoRunError(f"{tool} failed ({done.returncode}): {done.stderr.strip()[-2000:]}")
