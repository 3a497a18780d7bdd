"""The `assignment` associator: accuracy on seeded simulations, its invariants, robustness.

Thresholds sit a little below what was measured (docs/assignment.md has the measured table), and
well above what a structure-blind method reaches, so a regression fails them.
"""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import Detections, associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.associators.assignment import (
    AssignmentAssociator,
    AssignmentParams,
    Tails,
    within_time_scale,
)
from roadlink.association.associators.assignment.learning import best_skew, learn_segments
from roadlink.association.associators.assignment.matching import match
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import concatenate
from roadlink.simulation import SlowZone, preset, simulate


def mean_accuracy(name: str, seeds: range, **overrides: object) -> float:
    scores = []
    for seed in seeds:
        d = simulate(preset(name, **overrides), seed=seed).detections
        result = associate(d, "assignment")
        assert result.metrics is not None
        scores.append(result.metrics.accuracy)
    return float(np.mean(scores))


def grouping(d: Detections) -> np.ndarray:
    return AssignmentAssociator().group(d.without_labels())


def test_is_the_default_associator():
    """`associate` without a name runs `assignment`, with the same answer as naming it."""
    d = simulate(preset("medium"), seed=3).detections
    default = associate(d)
    assert DEFAULT_ASSOCIATOR == "assignment" and default.associator == "assignment"
    assert default.to_dict() == associate(d, "assignment").to_dict()


@pytest.mark.slow
@pytest.mark.parametrize("name", ["large", "medium", "small"])
def test_paper_presets(name):
    # The goal of issue 3: at least 99.5% on each preset. Measured over seeds 0-99: 99.74 /
    # 99.86 / 99.62% (over 0-19: 99.50 / 99.60 / 99.60%: one swapped pair moves a 20-seed mean
    # by up to half a point, so the goal is held over a hundred).
    assert mean_accuracy(name, range(100)) >= 0.995


@pytest.mark.slow
@pytest.mark.parametrize("name", ["large", "medium", "small"])
def test_missed_detections_and_false_alarms(name):
    # Goal: at least 97%. Measured over seeds 0-99: 99.5 / 99.5 / 99.2%.
    faults = {"miss_probability": 0.05, "false_alarm_rate": 0.05}
    assert mean_accuracy(name, range(100), **faults) >= 0.97


def test_congested_multilane_slow_zone():
    # Goal: at least 95% with 100+ targets. Measured 97.8% over seeds 0-19 (and over 0-99).
    assert mean_accuracy("congested", range(20)) >= 0.95


def test_one_detection_per_sensor_per_target():
    d = simulate(
        preset("congested", miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.1),
        seed=3,
    ).detections
    groups = grouping(d)
    assigned = groups >= 0
    pairs = np.column_stack(
        [groups[assigned], np.unique(d.position, return_inverse=True)[1][assigned]]
    )
    assert np.unique(pairs, axis=0).shape[0] == pairs.shape[0]


def test_false_alarms_are_left_unassigned():
    d = simulate(preset("medium", false_alarm_rate=0.1), seed=2).detections
    groups = grouping(d)
    clutter = d.target == "clutter"
    assert clutter.sum() > 5
    # Most false alarms stay out; a false alarm can only enter a target in place of a missing
    # real detection, and no real one is missing here.
    assert np.mean(groups[clutter] == -1) >= 0.9
    assert np.mean(groups[~clutter] >= 0) >= 0.99


def test_duplicates_join_no_target_twice_and_start_no_track():
    d = simulate(preset("medium", duplicate_probability=0.1), seed=5).detections
    result = associate(d, "assignment")
    assert result.metrics is not None
    # A duplicated passage leaves one report over, which counts as an error: the rest is right.
    duplicates = len(d) - 100
    assert result.metrics.accuracy >= (100 - 1.2 * duplicates) / len(d)
    assert result.to_dict()["n_targets"] == 10


def test_shuffled_and_relabelled_input_gives_the_same_grouping():
    d = simulate(
        preset("congested", miss_probability=0.05, false_alarm_rate=0.05), seed=1
    ).detections
    groups = grouping(d)
    order = np.random.default_rng(0).permutation(len(d))
    shuffled = d.take(order)
    relabelled = Detections(
        shuffled.position,
        shuffled.velocity,
        shuffled.timestamp,
        shuffled.sensor_id,
        np.array([f"x{i}" for i in range(len(d))], dtype=object),
        np.full(len(d), None, dtype=object),
    )
    again = np.empty_like(groups)
    again[order] = AssignmentAssociator().group(relabelled)
    # Same partition: the group numbers may differ, the pairing of detections may not.
    pairs = {(int(a), int(b)) for a, b in zip(groups, again, strict=True)}
    assert len({a for a, _ in pairs}) == len(pairs) == len({b for _, b in pairs})
    assert ((groups < 0) == (again < 0)).all()


def test_a_speed_near_zero_at_a_sensor_does_not_break_the_track():
    d = simulate(preset("large", velocity_model="constant"), seed=0).detections
    velocity = d.velocity.copy()
    # One target crawls past sensor 5 (a stop-and-go queue): its report there is 0.01 m/s.
    target = np.flatnonzero((d.target == "A3") & (d.position == 500.0))[0]
    velocity[target] = 0.01
    crawl = Detections(d.position, velocity, d.timestamp, d.sensor_id, d.detection_id, d.target)
    groups = grouping(crawl)
    result = associate(crawl, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.99
    a3 = groups[crawl.target == "A3"]
    # The track holds together around the crawling report, and nothing else is lost. The report
    # itself is left unassigned today: at a steady 30 m/s elsewhere, its 0.01 m/s reads as a
    # fault (real queues report such speeds for whole runs of vehicles; docs/sumo.md).
    assert groups[target] == -1
    a3_elsewhere = a3[a3 >= 0]
    assert a3_elsewhere.size == np.sum(crawl.target == "A3") - 1
    assert np.unique(a3_elsewhere).size == 1, "the crawl must not split the target"
    assert (groups[crawl.target != "A3"] >= 0).all()


def test_two_sensors_only():
    d = simulate(preset("large", sensor_positions=[0.0, 150.0]), seed=1).detections
    result = associate(d, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.9


def test_a_single_detection_and_a_lone_pair():
    lone = Detections.from_columns([0.0, 100.0], [30.0, 30.0], [0.0, 1000.0])
    assert (grouping(lone) == -1).all(), "no kinematic link: two false alarms"
    pair = Detections.from_columns([0.0, 100.0], [30.0, 30.0], [0.0, 100.0 / 30.0])
    groups = grouping(pair)
    assert groups[0] == groups[1] >= 0


def test_a_target_the_batch_cut_off_after_one_sensor_is_still_a_target():
    d = simulate(preset("medium"), seed=0).detections
    first, last = float(d.position.min()), float(d.position.max())
    begin, end = float(d.timestamp.min()), float(d.timestamp.max())
    middle = float(np.unique(d.position)[4])
    speed = float(np.median(d.velocity))
    # Passed the first sensor just before the batch ended; passed the last just after it began
    # (too early to have been seen upstream inside the batch); a lone report mid-road, mid-batch.
    extra = Detections.from_columns(
        [first, last, middle],
        [speed, speed, speed],
        [end - 1.0, begin + 1.0, 0.5 * (begin + end)],
        sensor_id=[d.sensor_id[d.position == x][0] for x in (first, last, middle)],
        detection_id=["x1", "x2", "x3"],
        target=["late", "early", "clutter"],
    )
    cut = concatenate([d, extra])
    groups = grouping(cut)
    late, early, lone = groups[-3:]
    assert late >= 0 and early >= 0 and late != early
    assert np.sum(groups == late) == 1 and np.sum(groups == early) == 1
    assert lone == -1, "a single report inside the batch's road and time is a false alarm"
    result = associate(cut, "assignment")
    assert result.metrics is not None and result.metrics.accuracy == 1.0
    # With min_track_length 1 no track is too short: the lone report is a target of its own.
    keep_all = AssignmentAssociator(min_track_length=1)
    assert keep_all.group(cut.without_labels())[-1] >= 0


def test_irregular_sensor_spacing():
    spacing = [0.0, 40.0, 260.0, 300.0, 620.0, 700.0, 1150.0, 1180.0, 1500.0]
    assert mean_accuracy("medium", range(10), sensor_positions=spacing) >= 0.99


def test_strong_slow_zone():
    # Measured 96.3% over seeds 0-9. Inside a zone at a tenth of the speed only the speeds tell
    # targets apart (what the speed weights cost here: CHANGELOG.md).
    zone = SlowZone(start=400.0, end=600.0, speed_factor=0.1)
    assert mean_accuracy("medium", range(10), slow_zone=zone) >= 0.95


def test_stop_and_go_zone_in_dense_traffic():
    # 120 targets through a zone at a tenth of their speed: the speed changes at a sensor, so the
    # prior must find each zone segment's bias among many unrelated pairs. Measured 83.8% over
    # seeds 0-9 (73.9% when the prior looked at all pairs alone: on four seeds it missed a bias).
    zone = SlowZone(start=400.0, end=600.0, speed_factor=0.1)
    assert mean_accuracy("congested", range(10), slow_zone=zone) >= 0.8


def test_progress_is_reported_up_to_one():
    seen: list[float] = []
    AssignmentAssociator().group(simulate(preset("small"), seed=0).detections, seen.append)
    assert seen and seen == sorted(seen) and seen[-1] == pytest.approx(1.0)


def test_match_takes_an_edge_only_when_it_beats_leaving_both_alone():
    left = np.array([0, 0, 1])
    right = np.array([10, 11, 10])
    cost = np.array([1.0, 5.0, 2.0])
    a, b = match(left, right, cost, gate=4.0)
    # 0-11 (5) exceeds the gate; 0-10 and 1-10 compete for 10: the cheaper one wins.
    assert dict(zip(a.tolist(), b.tolist(), strict=True)) == {0: 10}
    a, b = match(left, right, np.array([1.0, 3.0, 1.5]), gate=4.0)
    # Now 0-11 + 1-10 (4.5) beats 0-10 alone (1 + leaving 1 and 11 alone at 4).
    assert dict(zip(a.tolist(), b.tolist(), strict=True)) == {0: 11, 1: 10}


def test_sparse_matching_terminates_on_a_block_that_made_lapjvsp_cycle():
    # A dense block of SUMO bottleneck traffic (174 x 186 nodes, 8003 edges) on which scipy's
    # LAPJVsp looped forever with the raw float costs. It runs in a child process so that a
    # regression fails this test instead of hanging the suite.
    data = Path(__file__).parents[3] / "data" / "lapjvsp_cycle.npz"
    script = (
        "import numpy as np, sys\n"
        "from roadlink.association.associators.assignment.matching import _match_block\n"
        "z = np.load(sys.argv[1])\n"
        "left, right = _match_block(z['left'], z['right'], z['cost'], float(z['alone']))\n"
        "print(left.size, np.unique(left).size, np.unique(right).size)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script, str(data)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    matched, distinct_left, distinct_right = map(int, run.stdout.split())
    assert matched == distinct_left == distinct_right > 100  # one-to-one, and most nodes matched


def test_tails_cost_is_squared_in_the_core_and_flatter_beyond():
    r = np.linspace(0.0, 20.0, 81)
    assert np.allclose(Tails(0.0, 4.0).cost(r), r * r)
    heavy = Tails(0.1, 5.0)
    cost = heavy.cost(r)
    assert cost[0] == pytest.approx(0.0, abs=1e-12)
    assert np.all(np.diff(cost) > 0)
    assert np.allclose(cost[:3], r[:3] ** 2, rtol=0.1)  # the core is still r^2
    assert cost[-1] < 0.1 * 20.0**2  # 20 core spreads off is unlikely, not impossible
    # One large change is cheaper than two medium ones (a normal cost says the opposite).
    assert heavy.cost(np.array([10.0]))[0] < 2 * heavy.cost(np.array([5.0]))[0]


def test_tails_reach_is_where_the_cost_meets_the_budget():
    for tails in (Tails(0.0, 2.0), Tails(0.01, 3.0), Tails(0.2, 8.0)):
        reach = tails.reach(16.0)
        assert tails.cost(np.array([reach]))[0] <= 16.0 < tails.cost(np.array([reach * 1.02]))[0]


def test_tails_fit_recovers_a_known_mixture_and_finds_none_in_normal_data():
    rng = np.random.default_rng(0)
    core = rng.normal(size=9000)
    wide = 6.0 * rng.normal(size=1000)
    fitted = Tails.fit(np.concatenate([core, wide]), Tails(0.01, 3.0))
    assert fitted.weight == pytest.approx(0.1, abs=0.03)
    assert fitted.scale == pytest.approx(6.0, rel=0.15)
    assert Tails.fit(rng.normal(size=10000), Tails(0.05, 4.0)).weight < 0.02
    assert Tails.fit(np.zeros(5), Tails(0.05, 4.0)) == Tails(0.05, 4.0)  # too few: the prior


def queue(n_vehicles: int, speed: object, headway: float, n_sensors: int = 6) -> Detections:
    """Vehicles one `headway` apart; `speed(vehicle, sensor, time)` is the speed at a sensor. Each
    segment takes the mean of its ends' inverse speeds (the kinematic prediction is exact)."""
    positions = 250.0 * np.arange(n_sensors)
    rows = []
    for v in range(n_vehicles):
        t = v * headway
        for k, x in enumerate(positions):
            s = speed(v, k, t)  # type: ignore[operator]
            rows.append((x, s, t, f"V{v}"))
            if k + 1 < n_sensors:
                ahead = speed(v, k + 1, t + 250.0 / s)  # type: ignore[operator]
                t += 250.0 * 0.5 * (1.0 / s + 1.0 / ahead)
    position, velocity, time, target = zip(*rows, strict=True)
    return Detections.from_columns(list(position), list(velocity), list(time), target=list(target))


def test_a_dense_queue_keeps_the_kinematic_travel_time():
    # Stop-and-go: a congestion wave sweeps the road, speeds range over 4-16 m/s, a vehicle
    # every 1.5 s, travel times of 15-60 s. Unrelated pairs vastly outnumber true ones, so the
    # highest bump of the travel-time ratio over all pairs is chance: the kinematic model must
    # stand (`segment_prior`).
    # Measured 56% (44% before the segments learned their skew, 28% when the prior took chance
    # bumps for biases); the speeds, which swing by half between sensors, are what is still
    # hard here.
    d = queue(150, lambda v, k, t: 10.0 + 6.0 * np.sin(t / 15.0 - k), headway=1.5)
    result = associate(d, "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.5


def braking(seed: int, n_vehicles: int = 150) -> Detections:
    """Vehicles about a second apart keep their own speed (25-35 m/s) up to 480 m, then brake,
    each to a speed of its own (10-16 m/s), just before the sensor at 500 m, and keep it to the
    last sensor at 750 m; sensors measure speed to 1 %. The segment 250 -> 500 m is driven almost
    all at the first speed: the kinematic prediction, which weighs both ends' speeds alike, is
    off by 30-60 %, differently for every vehicle."""
    rng = np.random.default_rng(seed)
    start = np.cumsum(rng.exponential(1.0, n_vehicles))
    fast = rng.uniform(25.0, 35.0, n_vehicles)
    slow = rng.uniform(10.0, 16.0, n_vehicles)
    times = [start, start + 250.0 / fast, start + 480.0 / fast + 20.0 * 2.0 / (fast + slow)]
    times.append(times[2] + 250.0 / slow)
    speeds = [fast, fast, slow, slow]
    return Detections.from_columns(
        np.repeat([0.0, 250.0, 500.0, 750.0], n_vehicles),
        np.concatenate([v * np.exp(0.01 * rng.standard_normal(n_vehicles)) for v in speeds]),
        np.concatenate(times),
        target=[f"V{i}" for _ in range(4) for i in range(n_vehicles)],
    )


def test_learning_finds_which_end_of_a_segment_explains_its_travel_time():
    d = braking(0)
    params = AssignmentParams()
    s = arrange(d, params)
    _, truth = np.unique(d.target, return_inverse=True)
    prior = segment_prior(s, params.max_skip + 1, params)
    model = learn_segments(s, truth, params, prior)
    # Braking at 480 m: the segment 250 -> 500 m is explained by the speed at 250 m, and then
    # predicted to a few per cent (the symmetric prediction is off by 30-60 %).
    assert model.skew[1, 1] <= 0.1
    assert model.time_spread[1, 1] <= 0.03
    # Steady speeds: both ends explain the time alike, and the kinematic prediction stands.
    assert model.skew[0, 1] == model.skew[2, 1] == 0.5


def test_best_skew_finds_which_end_explains_the_travel_time():
    rng = np.random.default_rng(1)
    n = 200
    dx = np.full(n, 250.0)
    v_a, v_b = rng.uniform(25.0, 35.0, n), rng.uniform(10.0, 16.0, n)
    noise = np.exp(0.01 * rng.standard_normal(n))
    for w in (0.0, 0.2, 0.8, 1.0):
        dt = 1.3 * dx * ((1.0 - w) / v_a + w / v_b) * noise
        assert best_skew(dt, dx, v_a, v_b) == pytest.approx(w, abs=0.05)
    # Where both ends' speeds explain the time alike, the kinematic prediction stands.
    same = rng.uniform(25.0, 35.0, n)
    dt = dx / same * np.exp(0.02 * rng.standard_normal(n))
    assert best_skew(dt, dx, same, same * np.exp(0.02 * rng.standard_normal(n))) == 0.5
    assert best_skew(dt[:2], dx[:2], same[:2], same[:2]) == 0.5  # too few links to say


def in_hours(d: Detections) -> Detections:
    """The same detections timed in hours, with positions in km and speeds in km/h."""
    return Detections(
        d.position / 1000.0,
        d.velocity * 3.6,
        d.timestamp / 3600.0,
        d.sensor_id,
        d.detection_id,
        d.target,
    )


def test_parameters_in_time_units_follow_the_callers_time_unit():
    d = simulate(preset("medium"), seed=0).detections
    params = AssignmentParams()
    # Seconds: the defaults stand.
    assert within_time_scale(params, arrange(d, params).typical_travel_time()) == params
    # Hours: a 0.5 h duplicate window would take every report within half an hour of another
    # for a copy; both are held to shares of a travel time between sensors (about 3 s here).
    hours = within_time_scale(params, arrange(in_hours(d), params).typical_travel_time())
    assert 0.1 / 3600 < hours.duplicate_window < 1.0 / 3600
    assert hours.timestamp_noise < 0.1 / 3600


def test_the_result_reports_the_parameters_it_ran_with_next_to_those_asked_for():
    d = simulate(preset("medium"), seed=0).detections
    asked = {"duplicate_window": 0.4, "timestamp_noise": 0.03}
    seconds = associate(d, "assignment", asked).to_dict()
    assert seconds["params"]["duplicate_window"] == 0.4
    assert seconds["effective_params"] == seconds["params"]  # seconds: nothing held
    hours = associate(in_hours(d), "assignment", asked).to_dict()
    assert hours["params"] == seconds["params"]  # what was asked for, as asked
    typical = arrange(in_hours(d), AssignmentParams()).typical_travel_time()
    assert typical is not None and 2.0 / 3600 < typical < 5.0 / 3600  # 100 m at ~30 m/s
    effective = hours["effective_params"]
    assert effective["duplicate_window"] == pytest.approx(0.25 * typical, rel=1e-12)
    assert effective["timestamp_noise"] == pytest.approx(0.02 * typical, rel=1e-12)
    held = {"duplicate_window", "timestamp_noise"}
    assert {k: v for k, v in effective.items() if k not in held} == {
        k: v for k, v in hours["params"].items() if k not in held
    }
    # An associator that adapts nothing reports nothing.
    assert "effective_params" not in associate(d, "kmeans++").to_dict()


def test_a_deployment_timing_in_hours_is_grouped_as_well_as_one_timing_in_seconds():
    # Dense SUMO traffic (committed seed-0 case): 95.2% in seconds; in km, km/h and hours
    # measured 91.4% (16% when the time-unit parameters kept their seconds-sized defaults).
    committed = Path(__file__).parents[3] / "data" / "sumo" / "sumo-dense.csv"
    d = read_detections_csv(committed.read_text())
    result = associate(in_hours(d), "assignment")
    assert result.metrics is not None and result.metrics.accuracy >= 0.88


def test_no_track_crosses_a_gap_faster_than_its_sensors_ever_measured():
    # Committed SUMO bottleneck case (seed 0): in the queue the learned spreads are wide and the
    # tails heavy, and before this bound four links crossed 250 m in 0.4 s or less, one of them
    # backwards in time (a vehicle at the first sensor tied to another seen 0.7 s before it).
    committed = Path(__file__).parents[3] / "data" / "sumo" / "sumo-bottleneck.csv"
    d = read_detections_csv(committed.read_text())
    groups = associate(d, "assignment").groups
    order = np.lexsort((d.timestamp, d.position, groups))
    a, b = order[:-1], order[1:]
    linked = (groups[a] == groups[b]) & (groups[a] >= 0)
    a, b = a[linked], b[linked]
    fastest = {p: d.velocity[d.position == p].max() for p in np.unique(d.position)}
    top = np.maximum([fastest[p] for p in d.position[a]], [fastest[p] for p in d.position[b]])
    travel = d.timestamp[b] - d.timestamp[a]
    assert (travel > 0).all()
    assert (d.position[b] - d.position[a] <= 2.0 * top * travel).all()
