"""The `assignment` associator: accuracy on seeded simulations, its invariants, robustness.

Thresholds sit a little below what was measured (docs/assignment.md has the measured table), and
well above what a structure-blind method reaches, so a regression fails them.
"""

from pathlib import Path

import numpy as np
import pytest

from roadlink.association import Detections, associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.associators.assignment import (
    AssignmentAssociator,
    AssignmentParams,
    associator,
)
from roadlink.association.associators.assignment.sensors import arrange
from roadlink.association.associators.assignment.tracks import SweepSetup
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import concatenate
from roadlink.simulation import SlowZone, preset, simulate
from roadlink.simulation.sumo import SUMO_SCENARIOS
from tests.helpers import in_hours


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


def test_a_target_holds_one_passage_per_sensor():
    # One detection a sensor, and beside it only copies of that passage: reports of the same
    # sensor within duplicate_window (0.5 s) at a speed within 5 % (`duplicates`).
    d = simulate(
        preset("congested", miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.1),
        seed=3,
    ).detections
    groups = grouping(d)
    assigned = np.flatnonzero(groups >= 0)
    sensor = np.unique(d.position, return_inverse=True)[1]
    cells: dict[tuple[int, int], list[int]] = {}
    for i in assigned.tolist():
        cells.setdefault((int(groups[i]), int(sensor[i])), []).append(i)
    shared = [np.array(c) for c in cells.values() if len(c) > 1]
    assert 5 <= len(shared) < 0.1 * len(cells)
    for cell in shared:
        times, speeds = d.timestamp[cell], d.velocity[cell]
        assert np.ptp(times) <= 0.5 * (cell.size - 1)
        assert speeds.max() / speeds.min() <= 1.05 ** (cell.size - 1)


def test_false_alarms_are_left_unassigned():
    d = simulate(preset("medium", false_alarm_rate=0.1), seed=2).detections
    groups = grouping(d)
    clutter = d.target == "clutter"
    assert clutter.sum() > 5
    # Most false alarms stay out; a false alarm can only enter a target in place of a missing
    # real detection, and no real one is missing here.
    assert np.mean(groups[clutter] == -1) >= 0.9
    assert np.mean(groups[~clutter] >= 0) >= 0.99


def test_a_passage_reported_twice_is_one_vehicles_and_starts_no_track():
    d = simulate(preset("medium", duplicate_probability=0.1), seed=5).detections
    result = associate(d, "assignment")
    assert result.metrics is not None and len(d) - 100 >= 5
    # The copies join their vehicles' targets (left unassigned, each would count as an error:
    # 100 / 109 = 91.7 % at most); none starts a target of its own.
    assert result.metrics.accuracy >= 0.98
    assert result.to_dict()["n_targets"] == 10


@pytest.mark.parametrize("seed", range(5))
def test_the_copies_of_a_passage_are_in_its_vehicles_target(seed: int) -> None:
    d = simulate(preset("medium", duplicate_probability=0.1), seed=seed).detections
    groups = grouping(d)
    # A passage's reports: one vehicle's at one sensor.
    passage = np.char.add(d.target.astype(str), "@" + d.position.astype(str))
    names, count = np.unique(passage, return_counts=True)
    copied = [groups[passage == name] for name in names[count > 1]]
    together = [bool(g[0] >= 0 and (g == g[0]).all()) for g in copied]
    assert len(copied) >= 5 and np.mean(together) >= 0.85


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


@pytest.mark.parametrize(
    ("stage", "loop", "calls"),
    [("build_tracks", "em_rounds", 2), ("refine_boundaries", "refine_sweeps", 1)],
)
def test_a_round_or_sweep_that_changes_nothing_ends_its_loop(
    stage: str, loop: str, calls: int, monkeypatch: pytest.MonkeyPatch
) -> None:
    # On a paper-size batch the tracks of the first learned model are final, and the first
    # re-pairing sweep changes no link (judging them all as the last sweep would): every later
    # round or sweep would repeat the work, so each loop stops there, with what one gives.
    d = simulate(preset("small"), seed=0).detections.without_labels()
    seen: list[int] = []
    run = getattr(associator, stage)

    def counted(*args: object, **kwargs: object) -> object:
        seen.append(1)
        return run(*args, **kwargs)

    monkeypatch.setattr(associator, stage, counted)
    grouper = AssignmentAssociator(**{loop: 3})
    groups = grouper.group(d)
    assert len(seen) == calls
    once = AssignmentAssociator(**{loop: 1})
    np.testing.assert_array_equal(groups, once.group(d))
    np.testing.assert_array_equal(grouper.link_confidence, once.link_confidence)


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


@pytest.mark.parametrize("params", [{"feature_weight": 10.0}, {"gate_cost": 200.0}])
def test_no_link_runs_backwards_in_time_whatever_the_gate(params):
    """The gate's slack for the timestamps' error grows with its reach, and a feature's bonus
    widens the gate: at feature_weight 10 links ran 10-17 s backwards in time before the
    arrival window was held to a's own time."""
    config = preset(
        "large", n_targets=300, lanes=2, vehicle_lengths=True, vehicle_classes=True
    ).model_copy(update={"miss_probability": 0.05})
    d = simulate(config, seed=1).detections
    groups = associate(d, "assignment", params).groups
    order = np.lexsort((d.timestamp, d.position, groups))
    a, b = order[:-1], order[1:]
    linked = (groups[a] == groups[b]) & (groups[a] >= 0) & (d.position[b] > d.position[a])
    assert linked.sum() > 1000
    assert (d.timestamp[b[linked]] > d.timestamp[a[linked]]).all()


COMMITTED_SUMO = Path(__file__).parents[3] / "data" / "sumo"
# `assignment`'s accuracy on the committed seed-0 cases (benchmarks/sumo_accuracy.py measures
# them over more seeds), less a margin of 3 points: the test catches a regression, not a wobble.
MEASURED_ASSIGNMENT_ACCURACY = {
    "sumo-freeflow": 0.992,
    "sumo-dense": 0.952,
    "sumo-bottleneck": 0.525,
    "sumo-irregular": 0.943,
    "sumo-faulty": 0.789,
    # Queues, where `assignment` is weakest: the naive `chain` of benchmarks/references.py scores
    # 43 % on both (seeds 0-4), and given the true travel-time curves time and speed reach about
    # 55 % (benchmarks/queue_ceiling.py).
    "sumo-queue": 0.425,
    "sumo-stopgo": 0.405,
    # Traffic lights: over a segment with one, a vehicle's travel time is set by when it came
    # (green, or how far into the red), not by its speed; the naive chain scores 57.6 % here.
    "sumo-arterial": 0.607,
    # Junctions: vehicles leave and join the road between sensors (`assignment/ends.py`;
    # 0.878 before it).
    "sumo-junctions": 0.918,
}
MARGIN = 0.03


def test_every_sumo_scenario_has_a_measured_accuracy():
    assert sorted(MEASURED_ASSIGNMENT_ACCURACY) == sorted(SUMO_SCENARIOS)


@pytest.mark.parametrize("scenario", sorted(MEASURED_ASSIGNMENT_ACCURACY))
def test_assignment_on_committed_sumo_traffic_holds_its_measured_accuracy(scenario):
    d = read_detections_csv((COMMITTED_SUMO / f"{scenario}.csv").read_text())
    assert d.labelled.all() and d.sensor_positions.size >= 10
    result = associate(d, "assignment")
    assert result.metrics is not None
    assert result.metrics.accuracy >= MEASURED_ASSIGNMENT_ACCURACY[scenario] - MARGIN


# The same dense and free-flowing traffic seen by loops that read speeds with a 6 and a 10 %
# error (benchmarks/sumo_accuracy.py --speed-noise, seed 0, committed in tests/data/
# sumo-speed-noise): `assignment`'s accuracy, and what
# it was without the track's pace read from its travel times (`pace_weight=0`, as before
# `assignment/pace.py`).
MEASURED_WITH_SPEED_ERROR = {
    "sumo-dense-speed6": (0.883, 0.763),
    "sumo-freeflow-speed10": (0.974, 0.899),
}


@pytest.mark.parametrize("case", sorted(MEASURED_WITH_SPEED_ERROR))
def test_the_pace_holds_tracks_together_where_speeds_are_read_poorly(case):
    d = read_detections_csv(
        (COMMITTED_SUMO.parent / "sumo-speed-noise" / f"{case}.csv").read_text()
    )
    measured, without_pace = MEASURED_WITH_SPEED_ERROR[case]
    result = associate(d, "assignment")
    blind = associate(d, "assignment", {"pace_weight": 0.0})
    assert result.metrics is not None and blind.metrics is not None
    assert result.metrics.accuracy >= measured - MARGIN
    assert blind.metrics.accuracy == pytest.approx(without_pace, abs=0.005)
    assert result.metrics.accuracy >= blind.metrics.accuracy + 0.05


def test_a_sensors_speed_calibration_is_not_read_as_a_reading_error():
    """The irregular road seen by loops whose speeds are each off by a factor of their own
    (10 %, lognormal; benchmarks/sumo_accuracy.py --speed-noise, seed 0, committed in
    tests/data/sumo-speed-noise): the speed changes either side of a sensor shift by its
    factor, which read as they are looked like a reading error of every speed and turned the
    track's pace on (93.6 %). About each segment's mean change they show none: the grouping is
    that of the speeds alone (94.3 %)."""
    d = read_detections_csv(
        (COMMITTED_SUMO.parent / "sumo-speed-noise" / "sumo-irregular-bias10.csv").read_text()
    )
    result = associate(d, "assignment")
    speeds_alone = associate(d, "assignment", {"pace_weight": 0.0})
    assert result.metrics is not None
    assert np.array_equal(result.groups, speeds_alone.groups)
    assert result.metrics.accuracy >= 0.943 - MARGIN


def test_a_sweep_setup_whose_model_is_learned_from_is_dropped_before_learning(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    # A forward pass that may be the last works out the sweep's gating and window edges (two
    # numbers a detection); when its tracks are learned from, its model will not be the
    # sweep's, and holding them through learning made the association's peak at 10^6.
    n = 300
    config = preset("small").model_copy(
        update={
            "n_targets": n,
            "sensor_positions": [100.0 * i for i in range(20)],
            "start_time_range": (0.0, float(n)),
        }
    )
    d = simulate(config, seed=0).detections.without_labels()
    setups: list[SweepSetup] = []
    events: list[tuple[str, bool]] = []

    class Recorded(SweepSetup):
        def __init__(self) -> None:
            super().__init__()
            setups.append(self)

    build, learn = associator.build_tracks, associator.learn_segments

    def built(*args: object, **kwargs: object) -> object:
        events.append(("pass", args[8] is not None))  # with the sweep's setup to work out
        return build(*args, **kwargs)  # type: ignore[arg-type]

    def learned(*args: object, **kwargs: object) -> object:
        events.append(("learn", any(setup.edges is not None for setup in setups)))
        return learn(*args, **kwargs)  # type: ignore[arg-type]

    monkeypatch.setattr(associator, "SweepSetup", Recorded)
    monkeypatch.setattr(associator, "build_tracks", built)
    monkeypatch.setattr(associator, "learn_segments", learned)
    AssignmentAssociator().group(d)
    worked_out = events.index(("pass", True))
    assert any(kind == "learn" for kind, _ in events[worked_out:])  # that pass learned from
    assert not any(held for kind, held in events if kind == "learn")
    assert setups and setups[0].edges is not None  # the last pass's, for the sweep
