"""SUMO's input files and detector output (`simulation/sumo/files.py`): the network, routes and
loops written for a scenario, and the loops' output read back as detections."""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np
import pytest

from roadlink.simulation import sumo
from roadlink.simulation.sumo import (
    SUMO_SCENARIOS,
    Bottleneck,
    Ramp,
    Signal,
    connections_xml,
    detectors_xml,
    network_xml,
    parse_detector_output,
    road_segments,
    routes_xml,
    signals_xml,
    sumo_scenario,
)

DATA = Path(__file__).parents[1] / "data"


def test_detector_output_becomes_one_detection_per_vehicle_and_sensor():
    xml = (DATA / "instant_loops.xml").read_bytes()
    d = parse_detector_output(xml, {"S3": 700.0, "S4": 950.0})
    rows = list(zip(d.position, d.sensor_id, d.target, d.timestamp, d.velocity, strict=True))
    assert rows == [
        (700.0, "S3", "car.30", 64.49, 25.39),
        (700.0, "S3", "car.31", 69.85, 26.79),
        (700.0, "S3", "truck.4", 86.25, 20.65),
        (950.0, "S4", "car.30", 75.49, 21.56),
        (950.0, "S4", "car.31", 79.33, 24.48),
        # truck.4 changes lane over S4: lane 1's loop saw it first, lane 0's again at 98.50.
        (950.0, "S4", "truck.4", 98.33, 20.69),
    ]


def test_detector_output_is_cut_to_the_window_and_timed_from_its_start():
    xml = (DATA / "instant_loops.xml").read_bytes()
    d = parse_detector_output(xml, {"S3": 700.0, "S4": 950.0}, window=(70.0, 98.4))
    assert list(d.target) == ["truck.4", "car.30", "car.31", "truck.4"]
    np.testing.assert_allclose(d.timestamp, [16.25, 5.49, 9.33, 28.33])


def test_detector_output_names_an_unknown_detector():
    xml = (DATA / "instant_loops.xml").read_bytes()
    with pytest.raises(ValueError, match="detector 'S4:2' belongs to no known sensor"):
        parse_detector_output(xml, {"S3": 700.0})


def test_a_vehicle_entering_a_loop_at_standstill_reports_a_small_positive_speed():
    xml = (
        '<instantE1><instantOut id="S1:0" time="5.00" state="enter" vehID="car.1" '
        'speed="0.00"/></instantE1>'
    )
    d = parse_detector_output(xml, {"S1": 100.0})
    assert d.velocity.tolist() == [sumo.MIN_REPORTED_SPEED]


def test_with_features_each_detection_carries_its_loop_lane_and_the_vehicle_length_and_class():
    xml = (DATA / "instant_loops.xml").read_bytes()
    plain = parse_detector_output(xml, {"S3": 700.0, "S4": 950.0})
    assert plain.features == ()
    d = parse_detector_output(xml, {"S3": 700.0, "S4": 950.0}, features=True)
    assert d.timestamp.tolist() == plain.timestamp.tolist()
    # truck.4 is first seen by lane 1's loop at S4 (it changes lane over the sensor).
    rows = list(zip(d.target, d.lane.tolist(), d.length.tolist(), d.vehicle_class, strict=True))
    assert [r for r in rows if r[0] == "truck.4"] == [
        ("truck.4", 0, 12.0, "truck"),
        ("truck.4", 1, 12.0, "truck"),
    ]
    assert set(d.vehicle_class) == {"car", "truck"}


def test_with_features_each_class_is_a_distribution_of_spread_lengths():
    scenario = sumo_scenario("sumo-freeflow", features=True, vehicles=sumo.mix(car=0.9, van=0.1))
    routes = routes_xml(scenario)
    assert routes.count("<vTypeDistribution") == 2
    assert '<flow id="car" type="car"' in routes  # labels stay car.N
    car_lengths = sorted(
        float(t.split('length="')[1].split('"')[0]) for t in routes.splitlines() if 'id="car_' in t
    )
    assert len(car_lengths) == sumo.files.LENGTH_TYPES
    assert 3.6 < car_lengths[0] < 3.7 and 5.3 < car_lengths[-1] < 5.4
    assert "vTypeDistribution" not in routes_xml(sumo_scenario("sumo-freeflow"))


def test_a_bottleneck_cuts_the_road_into_three_edges():
    scenario = SUMO_SCENARIOS["sumo-bottleneck"]
    segments = road_segments(scenario)
    assert [(s.start, s.end, s.lanes) for s in segments] == [
        (0.0, 2000.0, 3),
        (2000.0, 2600.0, 1),
        (2600.0, 3000.0, 3),
    ]
    assert segments[1].speed_limit == pytest.approx(22.22)
    nodes, edges = network_xml(scenario)
    assert nodes.count("<node ") == 4 and edges.count("<edge ") == 3
    assert 'route id="road" edges="e0 e1 e2"' in routes_xml(scenario)


def test_a_signal_stands_at_a_traffic_light_junction_between_two_edges():
    scenario = sumo_scenario(
        "sumo-freeflow",
        bottleneck=Bottleneck(start=2000.0, end=2600.0, lanes=1),
        signals=[Signal(position=640.0), Signal(position=2300.0, green=30.0, offset=12.5)],
    )
    segments = road_segments(scenario)
    assert [(s.start, s.end, s.lanes) for s in segments] == [
        (0.0, 640.0, 3),
        (640.0, 2000.0, 3),
        (2000.0, 2300.0, 1),
        (2300.0, 2600.0, 1),
        (2600.0, 3000.0, 3),
    ]
    nodes, _ = network_xml(scenario)
    assert nodes.count('type="traffic_light"') == 2
    assert '<node id="n1" x="640.00" y="0.00" type="traffic_light"/>' in nodes
    assert '<node id="n3" x="2300.00" y="0.00" type="traffic_light"/>' in nodes
    # netconvert's own programmes (82 s green, 3 s amber, 5 s red), one link a lane.
    net = (
        '<net><tlLogic id="n1" type="static" programID="0" offset="0">'
        '<phase duration="82" state="GGG"/><phase duration="3" state="yyy"/>'
        '<phase duration="5" state="rrr"/></tlLogic>'
        '<tlLogic id="n3" type="static" programID="0" offset="0">'
        '<phase duration="82" state="G"/><phase duration="3" state="y"/>'
        '<phase duration="5" state="r"/></tlLogic></net>'
    )
    xml = signals_xml(scenario, net)
    assert xml.count("<tlLogic ") == 2 and 'programID="roadlink"' in xml
    assert '<tlLogic id="n1" type="static" programID="roadlink" offset="0">' in xml
    assert '<phase duration="40" state="GGG"/>' in xml
    assert '<phase duration="35" state="rrr"/>' in xml
    assert 'offset="12.5"' in xml and '<phase duration="30" state="G"/>' in xml
    assert '<phase duration="3" state="y"/>' in xml


def test_a_road_without_signals_has_no_traffic_light():
    scenario = SUMO_SCENARIOS["sumo-freeflow"]
    assert "traffic_light" not in network_xml(scenario)[0]
    assert signals_xml(scenario, "<net/>") == "<additional>\n</additional>\n"


def test_every_lane_at_every_sensor_has_a_loop_placed_on_the_lane_geometry():
    scenario = sumo_scenario(
        "sumo-freeflow",
        sensor_positions=[500.0, 1500.0, 2500.0],
        bottleneck=Bottleneck(start=1000.0, end=2000.0, lanes=2),
    )
    # What netconvert writes: each edge shortened by its junctions (lane shapes start later).
    net = "<net>" + "".join(
        f'<edge id="{edge}"><lane id="{edge}_{k}" length="{length}" '
        f'shape="{x0},{-1.6 - 3.2 * k} {x0 + length},{-1.6 - 3.2 * k}"/></edge>'
        for edge, lanes, x0, length in [("e0", 3, 0.0, 996.0), ("e1", 2, 1004.0, 992.0)]
        for k in range(lanes)
    )
    net += '<edge id="e2"><lane id="e2_0" length="996" shape="2004,-1.6 3000,-1.6"/>'
    net += '<lane id="e2_1" length="996" shape="2004,-4.8 3000,-4.8"/>'
    net += '<lane id="e2_2" length="996" shape="2004,-8 3000,-8"/></edge></net>'
    xml = detectors_xml(scenario, net, "out.xml")
    assert xml.count("<instantInductionLoop ") == 3 + 2 + 3
    assert 'id="S2:1" lane="e1_1" pos="496.00"' in xml
    assert 'id="S3:2" lane="e2_2" pos="496.00"' in xml
    assert 'id="S1:0" lane="e0_0" pos="500.00"' in xml


JUNCTIONS = [
    Ramp(position=830.0, kind="off", share=0.2),
    Ramp(position=1070.0, kind="on", demand=720.0),
]


def test_a_ramp_adds_a_lane_beside_the_road_where_it_meets_it():
    scenario = sumo_scenario("sumo-freeflow", ramps=JUNCTIONS)
    segments = road_segments(scenario)
    # The off-ramp's deceleration lane before it, the on-ramp's acceleration lane after it.
    assert [(s.start, s.end, s.lanes) for s in segments] == [
        (0.0, 680.0, 3),
        (680.0, 830.0, 4),
        (830.0, 1070.0, 3),
        (1070.0, 1320.0, 4),
        (1320.0, 3000.0, 3),
    ]
    nodes, edges = network_xml(scenario)
    assert '<node id="r1" x="1130.00" y="-60.00"/>' in nodes  # beyond the off-ramp's junction
    assert '<node id="r2" x="770.00" y="-60.00"/>' in nodes  # before the on-ramp's
    assert '<edge id="off1" from="n2" to="r1" numLanes="1" speed="22.22"/>' in edges
    assert '<edge id="on2" from="r2" to="n3" numLanes="1" speed="22.22"/>' in edges


def test_around_a_ramp_the_added_lane_leads_onto_it_or_merges_into_the_road():
    xml = connections_xml(sumo_scenario("sumo-freeflow", ramps=JUNCTIONS))
    connections = {
        (c.get("from"), int(c.get("fromLane", -1)), c.get("to"), int(c.get("toLane", -1)))
        for c in ET.fromstring(xml).iter("connection")
    }
    # Off-ramp: the road's lanes shift right by one onto the 4-lane edge, whose lane 0 (also
    # reachable from lane 0) leads only onto the ramp.
    assert {("e0", i, "e1", i + 1) for i in range(3)} <= connections
    assert ("e0", 0, "e1", 0) in connections
    assert ("e1", 0, "off1", 0) in connections
    assert {("e1", i + 1, "e2", i) for i in range(3)} <= connections
    # On-ramp: the ramp joins lane 0 of the acceleration stretch, which ends without a way on.
    assert ("on2", 0, "e3", 0) in connections
    assert {("e2", i, "e3", i + 1) for i in range(3)} <= connections
    assert {("e3", i + 1, "e4", i) for i in range(3)} <= connections
    assert not any(c[:2] == ("e3", 0) for c in connections)
    assert connections_xml(SUMO_SCENARIOS["sumo-freeflow"]) == "<connections>\n</connections>\n"


def test_vehicles_join_at_on_ramps_and_leave_by_off_ramps_as_their_shares_say():
    scenario = sumo_scenario(
        "sumo-freeflow", ramps=[*JUNCTIONS, Ramp(position=2000.0, kind="off", share=0.5)]
    )
    routes = ET.fromstring(routes_xml(scenario))
    distributions = {d.get("id"): d for d in routes.iter("routeDistribution")}
    assert sorted(distributions) == ["on2", "road"]
    road = {r.get("id"): r for r in distributions["road"].iter("route")}
    assert road["road_off1"].get("edges") == "e0 e1 off1"
    assert road["road_off3"].get("edges") == "e0 e1 e2 e3 e4 e5 off3"
    assert road["road_through"].get("edges") == "e0 e1 e2 e3 e4 e5 e6"
    shares = [
        float(road[r].get("probability", 0)) for r in ("road_off1", "road_off3", "road_through")
    ]
    assert shares == pytest.approx([0.2, 0.8 * 0.5, 0.8 * 0.5])
    joining = {r.get("id"): r.get("edges") for r in distributions["on2"].iter("route")}
    assert joining == {"on2_off3": "on2 e3 e4 e5 off3", "on2_through": "on2 e3 e4 e5 e6"}
    flows = {f.get("id"): f for f in routes.iter("flow")}
    assert flows["car-on2"].get("route") == "on2" and flows["car"].get("route") == "road"
    # The on-ramp's 720 veh/h in the road's mix (90 % cars): 648 an hour.
    assert flows["car-on2"].get("period") == f"exp({648 / 3600:.6f})"


def test_a_road_without_off_ramps_keeps_its_one_route():
    routes = routes_xml(SUMO_SCENARIOS["sumo-freeflow"])
    assert "routeDistribution" not in routes and '<route id="road" edges="e0"/>' in routes
