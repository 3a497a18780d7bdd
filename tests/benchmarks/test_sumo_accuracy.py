"""benchmarks/sumo_accuracy.py: its scenario groups, and that the speed-noise variants add a
speed error and nothing else."""

import argparse
import re

import numpy as np
import pytest

from benchmarks import sumo_accuracy as bench
from roadlink.association.detections import Detections
from roadlink.simulation.sumo import SUMO_SCENARIOS, DetectorFaults, run_sumo, sumo_available


def test_every_scenario_name_belongs_to_one_group():
    names = [name for group in bench.SCENARIO_GROUPS.values() for name in group]
    assert len(names) == len(set(names))
    assert set(bench.SCENARIO_GROUPS["main"]) == set(SUMO_SCENARIOS)
    assert set(bench.SCENARIO_GROUPS) == {"main", "validation", "speed-noise", "holdout"}


def test_the_speed_noise_variants_change_the_speed_error_alone():
    assert set(bench.SPEED_NOISE) == {
        f"sumo-{base}-speed{percent}" for base in ("freeflow", "dense") for percent in (3, 6, 10)
    } | {f"sumo-{base}-bias10" for base in ("freeflow", "dense", "irregular")}
    for name, scenario in bench.SPEED_NOISE.items():
        base_name, kind, percent = re.fullmatch(r"(.+)-(speed|bias)(\d+)", name).groups()
        base = SUMO_SCENARIOS[base_name]
        error = {"speed": "velocity_noise", "bias": "velocity_bias"}[kind]
        assert scenario.faults == DetectorFaults(**{error: int(percent) / 100})
        changed = {
            field
            for field in type(scenario).model_fields
            if getattr(scenario, field) != getattr(base, field)
        }
        assert changed == {"faults", "description"}


@pytest.mark.skipif(
    not sumo_available(), reason="Eclipse SUMO is not installed (pip install 'roadlink[sumo]')"
)
def test_a_speed_noise_case_is_its_base_case_with_noisy_speeds():
    base = run_sumo(SUMO_SCENARIOS["sumo-freeflow"], seed=0)
    noisy = bench.load_case("sumo-freeflow-speed6", 0, data=None, export=None)
    assert np.array_equal(noisy.timestamp, base.timestamp)
    assert np.array_equal(noisy.target, base.target)
    error = np.log(noisy.velocity / base.velocity)
    assert 0.05 < np.std(error) < 0.07


def test_with_features_adds_the_features_and_the_length_error_and_keeps_the_other_faults():
    faulty = SUMO_SCENARIOS["sumo-faulty"]
    featured = bench.with_features(faulty, 0.07)
    assert featured.features and featured.faults.length_noise == 0.07
    assert featured.faults.model_copy(update={"length_noise": 0.0}) == faulty.faults
    assert featured.sensor_positions == faulty.sensor_positions


def test_a_case_is_scored_as_detectors_reporting_all_none_or_the_lane_would_see_it():
    d = Detections.from_columns(
        [0.0, 100.0], [20.0, 20.0], [0.0, 5.0], lane=[0, 1], length=[4.0, 4.1]
    )
    assert bench.with_reported(d, "all").features == ("lane", "length")
    assert bench.with_reported(d, "none").features == ()
    assert bench.with_reported(d, "lane").features == ("lane",)
    assert set(bench.FEATURE_SUFFIX) == {"all", "none", "lane"}


def five_sensors() -> Detections:
    """Five sensors 100 m apart, two reports each at 20 m/s, stamped 0-9 s in road order."""
    return Detections.from_columns(
        np.repeat([0.0, 100.0, 200.0, 300.0, 400.0], 2), np.full(10, 20.0), np.arange(10.0)
    )


def test_a_late_or_early_clock_shifts_the_middle_sensor_alone_and_a_spread_every_sensor():
    d = five_sensors()
    late = bench.with_clock(d, "late2", seed=0)
    np.testing.assert_array_equal(late.timestamp - d.timestamp, np.where(d.position == 200, 2, 0))
    early = bench.with_clock(d, "early0.5", seed=0)
    middle = np.where(d.position == 200, -0.5, 0)
    np.testing.assert_array_equal(early.timestamp - d.timestamp, middle)
    spread = bench.with_clock(d, "spread1", seed=3).timestamp - d.timestamp
    assert np.unique(spread.round(9)).size == 5  # one offset a sensor, alike for its detections
    np.testing.assert_allclose(spread[::2], spread[1::2])
    again = bench.with_clock(d, "spread1", seed=3).timestamp - d.timestamp
    np.testing.assert_array_equal(spread, again)
    assert bench.with_clock(d, None, seed=0) is d
    with pytest.raises(ValueError, match="lateS"):
        bench.with_clock(d, "slow2", seed=0)
    first = bench.with_clock(d, "late3600first", seed=0).timestamp - d.timestamp
    np.testing.assert_array_equal(first, np.where(d.position == 0, 3600, 0))
    last = bench.with_clock(d, "early60last", seed=0).timestamp - d.timestamp
    np.testing.assert_array_equal(last, np.where(d.position == 400, -60, 0))
    with pytest.raises(ValueError, match="every sensor"):
        bench.with_clock(d, "spread1last", seed=0)


def test_a_drifting_clock_and_a_jitter_move_times_as_named():
    d = five_sensors()
    drift = bench.with_clock(d, "drift9", seed=0).timestamp - d.timestamp
    # Times 0-9: the middle sensor's reports at 4 and 5 s are 4 and 5 s late.
    np.testing.assert_allclose(drift, np.where(d.position == 200, d.timestamp, 0.0))
    saw = bench.with_clock(d, "saw9", seed=0).timestamp - d.timestamp
    # Set right at the middle time (4.5 s): 8 s late at 4 s, 1 s late at 5 s.
    np.testing.assert_allclose(saw, np.where(d.position == 200, (2 * d.timestamp) % 9, 0.0))
    jitter = bench.with_clock(d, "jitter0.5", seed=1).timestamp - d.timestamp
    assert np.unique(jitter).size == 10 and 0.1 < jitter.std() < 1.0
    np.testing.assert_array_equal(
        jitter, bench.with_clock(d, "jitter0.5", seed=1).timestamp - d.timestamp
    )
    with pytest.raises(ValueError, match="every sensor"):
        bench.with_clock(d, "jitter1first", seed=0)


def test_a_clock_step_shifts_the_middle_sensor_after_the_batch_middle_time_alone():
    # Times 0-9, median 4.5: the middle sensor's reports at 4 and 5 s; only the one at 5 s moves.
    d = five_sensors()
    step = bench.with_clock(d, "step20", seed=0).timestamp - d.timestamp
    np.testing.assert_array_equal(step, np.where((d.position == 200) & (d.timestamp > 4.5), 20, 0))


def test_a_quiet_middle_sensor_keeps_its_first_or_last_reports_alone():
    # Five sensors with four reports each; the middle one's come at 3, 2, 1, 0 s (unordered).
    d = Detections.from_columns(
        np.repeat([0.0, 100.0, 200.0, 300.0, 400.0], 4),
        np.full(20, 20.0),
        np.r_[np.arange(8.0), [3.0, 2.0, 1.0, 0.0], np.arange(8.0)],
    )
    first = bench.with_quiet(d, "first1")
    assert first.timestamp[first.position == 200].tolist() == [0.0]
    assert (first.position != 200).sum() == 16
    last = bench.with_quiet(d, "last3")
    assert sorted(last.timestamp[last.position == 200].tolist()) == [1.0, 2.0, 3.0]
    assert len(bench.with_quiet(d, "last9")) == 20
    assert bench.with_quiet(d, None) is d
    with pytest.raises(ValueError, match="firstN"):
        bench.with_quiet(d, "early2")


def test_a_speed_factor_scales_one_sensors_speeds_alone():
    d = five_sensors()
    slow = bench.with_speed_factor(d, "0.7")
    np.testing.assert_allclose(slow.velocity, np.where(d.position == 200, 14.0, 20.0))
    np.testing.assert_array_equal(slow.timestamp, d.timestamp)
    fast = bench.with_speed_factor(d, "1.5last")
    np.testing.assert_allclose(fast.velocity, np.where(d.position == 400, 30.0, 20.0))
    assert bench.with_speed_factor(d, None) is d
    for wrong in ("0", "fast", "0.7middle"):
        with pytest.raises(ValueError, match="Ffirst or Flast"):
            bench.with_speed_factor(d, wrong)


def test_coarse_readings_stamp_whole_steps_and_read_whole_units():
    d = Detections.from_columns([0.0, 100.0, 200.0], [10.0, 27.8, 0.1], [0.26, 5.74, 9.5])
    np.testing.assert_allclose(bench.with_readings(d, 0.5, None).timestamp, [0.5, 5.5, 9.5])
    np.testing.assert_array_equal(bench.with_readings(d, 1.0, None).velocity, d.velocity)
    kmh = bench.with_readings(d, None, "kmh")
    np.testing.assert_allclose(kmh.velocity * 3.6, [36.0, 100.0, 1.0])  # never 0
    np.testing.assert_array_equal(kmh.timestamp, d.timestamp)
    mph = bench.with_readings(d, None, "mph").velocity / 0.44704
    np.testing.assert_allclose(mph, [22.0, 62.0, 1.0])


@pytest.mark.parametrize(
    ("parse", "good", "bad", "says"),
    [
        (bench.parse_clock, "late20first", "slow2", "lateS"),
        # Accepted by the pattern, but no one sensor's clock moves every sensor's.
        (bench.parse_clock, "drift10", "spread1last", "every sensor"),
        (bench.parse_quiet, "first10", "early2", "firstN"),
        (bench.parse_speed_factor, "0.7last", "0", "F > 0"),
    ],
)
def test_a_fault_option_is_checked_as_it_is_read(parse, good, bad, says):
    # Before any case is simulated: argparse reports the error and exits.
    check = bench.checked(parse)
    assert check(good) == good
    with pytest.raises(argparse.ArgumentTypeError, match=says):
        check(bad)
