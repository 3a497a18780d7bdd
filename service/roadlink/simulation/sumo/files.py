"""SUMO's input files (network, routes, detectors) written from a scenario, and its detector
output read back as labelled detections. Plain text in and out: no SUMO needed to test it."""

from __future__ import annotations

import math
import xml.etree.ElementTree as ET
from collections.abc import Mapping

from roadlink.association.detections import Detections
from roadlink.simulation.sumo.scenarios import (
    YELLOW,
    RoadSegment,
    SumoScenario,
    VehicleClass,
    road_segments,
    sensor_ids,
)

# A loop reports the speed of a vehicle crawling over it as small but positive (its speed comes
# from the time the vehicle occupies it); SUMO may report exactly 0 for a vehicle that stopped
# within the step it entered, which no real detector reports and `Detections` rejects.
MIN_REPORTED_SPEED = 0.1

# A class with a length range is simulated as this many vehicle types of evenly spread lengths,
# each as likely (SUMO's lengths are per type): steps of 0.1 m for cars, well below what a
# loop's 5-10 % length error can tell apart.
LENGTH_TYPES = 20

# Detectors stay this far from an edge's ends, where SUMO's junction lanes begin.
EDGE_MARGIN = 0.5

# A ramp is one lane, this long (m) and this far beside the road (m), at this speed limit
# (m/s; 80 km/h, or the road's own where lower).
RAMP_LENGTH = 300.0
RAMP_OFFSET = 60.0
RAMP_SPEED = 22.22


def network_xml(scenario: SumoScenario) -> tuple[str, str]:
    """Plain nodes and edges XML of the road (for netconvert); the road runs along x from 0. A
    signal's node is a traffic light (`signals_xml` gives its programme); a ramp is an edge of
    its own into (``on1``) or out of (``off2``) the road's node where it meets the road."""
    segments = road_segments(scenario)
    xs = [segments[0].start] + [s.end for s in segments]
    lights = {signal.position for signal in scenario.signals}
    nodes = "".join(
        f'  <node id="n{k}" x="{x:.2f}" y="0.00"'
        + (' type="traffic_light"' if x in lights else "")
        + "/>\n"
        for k, x in enumerate(xs)
    )
    edges = "".join(
        f'  <edge id="{s.edge}" from="n{k}" to="n{k + 1}" numLanes="{s.lanes}" '
        f'speed="{s.speed_limit:.2f}"/>\n'
        for k, s in enumerate(segments)
    )
    speed = min(RAMP_SPEED, scenario.speed_limit)
    for j, ramp in enumerate(scenario.ramps, start=1):
        junction = f"n{xs.index(ramp.position)}"
        side = ramp.position + (RAMP_LENGTH if ramp.kind == "off" else -RAMP_LENGTH)
        nodes += f'  <node id="r{j}" x="{side:.2f}" y="{-RAMP_OFFSET:.2f}"/>\n'
        ends = (junction, f"r{j}") if ramp.kind == "off" else (f"r{j}", junction)
        edges += (
            f'  <edge id="{ramp.kind}{j}" from="{ends[0]}" to="{ends[1]}" numLanes="1" '
            f'speed="{speed:.2f}"/>\n'
        )
    return f"<nodes>\n{nodes}</nodes>\n", f"<edges>\n{edges}</edges>\n"


def connections_xml(scenario: SumoScenario) -> str:
    """Which lane leads to which around each ramp (for netconvert): an on-ramp joins the lane
    it adds, whose vehicles must merge left before it ends; the lane an off-ramp adds leads
    only onto the ramp. Elsewhere netconvert's own connections hold."""
    segments = road_segments(scenario)
    lines = ["<connections>"]
    for j, ramp in enumerate(scenario.ramps, start=1):
        k = next(k for k, s in enumerate(segments) if s.start == ramp.added_lane[0])
        before, wide, after = segments[k - 1], segments[k], segments[k + 1]
        into = [(before.edge, i, wide.edge, i + 1) for i in range(before.lanes)]
        out = [(wide.edge, i + 1, after.edge, i) for i in range(after.lanes)]
        if ramp.kind == "on":
            into.append((f"on{j}", 0, wide.edge, 0))
        else:
            into.append((before.edge, 0, wide.edge, 0))
            out.append((wide.edge, 0, f"off{j}", 0))
        lines.extend(
            f'  <connection from="{a}" to="{b}" fromLane="{i}" toLane="{o}"/>'
            for a, i, b, o in into + out
        )
    lines.append("</connections>")
    return "\n".join(lines) + "\n"


def signals_xml(scenario: SumoScenario, net_xml: str) -> str:
    """Each signal's fixed-time programme (green, YELLOW amber, red), replacing the one
    netconvert made for its node (82 s green, 3 s amber, 5 s red): its links, one a lane, all
    shown the same light. An additional file, loaded after the network."""
    segments = road_segments(scenario)
    node_of = {segment.end: f"n{k + 1}" for k, segment in enumerate(segments)}
    links = {
        tl.get("id"): len(tl.find("phase").get("state", ""))  # type: ignore[union-attr]
        for tl in ET.fromstring(net_xml).iter("tlLogic")
    }
    lines = ["<additional>"]
    for signal in scenario.signals:
        node = node_of[signal.position]
        n = links[node]
        lines.append(
            f'  <tlLogic id="{node}" type="static" programID="roadlink" offset="{signal.offset:g}">'
        )
        for duration, light in ((signal.green, "G"), (YELLOW, "y"), (signal.red, "r")):
            lines.append(f'    <phase duration="{duration:g}" state="{light * n}"/>')
        lines.append("  </tlLogic>")
    lines.append("</additional>")
    return "\n".join(lines) + "\n"


def routes_xml(scenario: SumoScenario) -> str:
    """Vehicle types and one Poisson flow per vehicle class over the whole road, and one per
    class from each on-ramp; where there are off-ramps, each flow's vehicles take them as their
    shares say (a route distribution)."""
    segments = road_segments(scenario)
    total = sum(v.share for v in scenario.vehicles)
    end = scenario.warmup + scenario.duration
    lines = ["<routes>"]
    for v in scenario.vehicles:
        lines.extend(_vehicle_types(v, spread=scenario.features))
    origins = [("road", "", 0.0, scenario.demand)]
    origins += [
        (f"on{j}", f"-on{j}", ramp.position, ramp.demand)
        for j, ramp in enumerate(scenario.ramps, start=1)
        if ramp.kind == "on"
    ]
    for route, _, entry, _ in origins:
        lines.extend(_routes(scenario, segments, route, entry))
    for route, suffix, _, demand in origins:
        for v in scenario.vehicles:
            rate = demand * v.share / total / 3600.0  # vehicles per second
            lines.append(
                f'  <flow id="{v.name}{suffix}" type="{v.name}" route="{route}" begin="0" '
                f'end="{end}" period="exp({rate:.6f})" departLane="free" departSpeed="max"/>'
            )
    lines.append("</routes>")
    return "\n".join(lines) + "\n"


def _routes(
    scenario: SumoScenario, segments: list[RoadSegment], name: str, entry: float
) -> list[str]:
    """The route named `name` of vehicles entering the road at `entry` (0: its start, else an
    on-ramp of that name): one route to the road's end, or, where off-ramps lie beyond the
    entry, a distribution over leaving at each of them or staying on."""
    first = [] if entry == 0.0 else [name]
    edges = [s.edge for s in segments if s.start >= entry]
    exits = [
        (f"off{j}", ramp)
        for j, ramp in enumerate(scenario.ramps, start=1)
        if ramp.kind == "off" and ramp.position > entry
    ]
    if not exits:
        return [f'  <route id="{name}" edges="{" ".join(first + edges)}"/>']
    lines = [f'  <routeDistribution id="{name}">']
    staying = 1.0
    for exit_edge, ramp in sorted(exits, key=lambda e: e[1].position):
        before = [s.edge for s in segments if entry <= s.start < ramp.position]
        lines.append(
            f'    <route id="{name}_{exit_edge}" edges="{" ".join(first + before + [exit_edge])}" '
            f'probability="{staying * ramp.share:.6f}"/>'
        )
        staying *= 1.0 - ramp.share
    lines.append(
        f'    <route id="{name}_through" edges="{" ".join(first + edges)}" '
        f'probability="{staying:.6f}"/>'
    )
    lines.append("  </routeDistribution>")
    return lines


def _vehicle_types(v: VehicleClass, spread: bool) -> list[str]:
    """The class as one vType, or, with `spread` and a length range, as a distribution (named
    after the class, so flows and labels stay as they are) of types ``car_0``, ``car_1``, ...
    of evenly spread lengths."""
    if not spread or v.length_range is None:
        return [_vehicle_type(v, v.name, v.length)]
    low, high = v.length_range
    step = (high - low) / LENGTH_TYPES
    types = [
        "  " + _vehicle_type(v, f"{v.name}_{k}", low + (k + 0.5) * step)
        for k in range(LENGTH_TYPES)
    ]
    return [f'  <vTypeDistribution id="{v.name}">', *types, "  </vTypeDistribution>"]


def _vehicle_type(v: VehicleClass, type_id: str, length: float) -> str:
    # Desired-speed factors are normal, cut at +-3 std (and kept positive).
    dev = v.speed_deviation
    low, high = max(0.2, v.speed_factor - 3 * dev), v.speed_factor + 3 * dev
    return (
        f'  <vType id="{type_id}" vClass="{v.vclass}" length="{length:g}" '
        f'maxSpeed="{v.max_speed}" accel="{v.accel}" decel="{v.decel}" sigma="{v.sigma}" '
        f'speedFactor="normc({v.speed_factor},{dev},{low:.3f},{high:.3f})"/>'
    )


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
    features: bool = False,
) -> Detections:
    """SUMO instantInductionLoop output as labelled detections.

    Detector ids are ``SENSOR:LANE``; `sensors` maps each sensor id to its position. Every
    vehicle's first ``enter`` at a sensor is its detection (a vehicle changing lanes over a sensor
    can enter a second lane's loop; one sensor is all its lanes, so that is not a new passage).
    Only entries with ``window[0] <= time < window[1]`` are kept, their timestamps counted from
    ``window[0]``. The target label is SUMO's vehicle id. With `features`, each detection carries
    its loop's lane, the vehicle's true length and its class (its vType's name up to ``_``).
    """
    start, end = window if window is not None else (-math.inf, math.inf)
    first: dict[tuple[str, str], ET.Element] = {}
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
        if key not in first or time < float(first[key].attrib["time"]):
            first[key] = event
    order = sorted(first, key=lambda k: (sensors[k[0]], float(first[k].attrib["time"])))
    events = [first[k] for k in order]
    origin = start if math.isfinite(start) else 0.0
    return Detections.from_columns(
        [sensors[s] for s, _ in order],
        [max(float(e.attrib["speed"]), MIN_REPORTED_SPEED) for e in events],
        # SUMO writes times to 0.01 s; rounding drops the float noise of the subtraction.
        [round(float(e.attrib["time"]) - origin, 6) for e in events],
        sensor_id=[s for s, _ in order],
        target=[vehicle for _, vehicle in order],
        lane=[int(e.attrib["id"].rsplit(":", 1)[1]) for e in events] if features else None,
        length=[float(e.attrib["length"]) for e in events] if features else None,
        vehicle_class=[e.attrib["type"].split("_")[0] for e in events] if features else None,
    )
