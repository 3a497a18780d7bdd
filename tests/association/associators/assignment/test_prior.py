"""The prior (`assignment/prior.py`): what the detections say about every segment before any of
them is linked: a travel-time bias where the pairs pile up, the kinematic prediction where they
do not, and sums of the segments' travel times over missed sensors."""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.prior import (
    PRIOR_BINS,
    BiasHistogram,
    FewPairs,
    bin_counts,
    excess_centres,
    few_targets_priors,
    segment_prior,
    travel_time_bumps,
)
from roadlink.association.associators.assignment.sensors import KINEMATIC_SKEW, arrange
from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate
from tests.association.associators.assignment.roads import sensor_cut

PARAMS = AssignmentParams()
SLOW = 1.5  # the slow zone's travel time over the kinematic one


def slow_zone(seed: int, n: int = 200) -> Detections:
    """`n` vehicles, 2 s apart on average at 20-35 m/s of their own, past sensors at 0, 200,
    400 and 500 m; the first segment takes them SLOW times the kinematic travel time (a slow
    zone between two sensors), the others exactly it; speeds are measured to 1 %."""
    rng = np.random.default_rng(seed)
    start = np.cumsum(rng.exponential(2.0, n))
    v = rng.uniform(20.0, 35.0, n)
    first = start + SLOW * 200.0 / v
    times = [start, first, first + 200.0 / v, first + 300.0 / v]
    return Detections.from_columns(
        np.repeat([0.0, 200.0, 400.0, 500.0], n),
        np.tile(v, 4) * np.exp(0.01 * rng.standard_normal(4 * n)),
        np.concatenate(times),
    )


def test_a_slow_zone_shows_before_anything_is_linked_and_the_other_segments_stay_kinematic():
    model = segment_prior(arrange(slow_zone(0), PARAMS), 3, PARAMS)
    bias = np.exp(model.log_bias)
    assert bias[0, 1] == pytest.approx(SLOW, rel=0.02)
    assert bias[1, 1] == pytest.approx(1.0, abs=0.01) and bias[2, 1] == 1.0
    # Over a missed sensor the typical travel times add up: (1.5 * 200 + 200) m / 400 m, and
    # 1.5 * 200 + 300 over 500 m.
    assert bias[0, 2] == pytest.approx(500.0 / 400.0, rel=0.02)
    assert bias[0, 3] == pytest.approx(600.0 / 500.0, rel=0.02)
    assert bias[1, 2] == pytest.approx(1.0, abs=0.01)


def test_unrelated_arrivals_leave_the_kinematic_prediction():
    # Two sensors each seeing its own traffic: no pair is one vehicle, so no bias is believed.
    rng = np.random.default_rng(1)
    n = 200
    d = Detections.from_columns(
        np.repeat([0.0, 200.0], n),
        rng.uniform(20.0, 35.0, 2 * n),
        np.concatenate([np.sort(rng.uniform(0, 400, n)), np.sort(rng.uniform(0, 400, n))]),
    )
    assert np.all(segment_prior(arrange(d, PARAMS), 3, PARAMS).log_bias == 0.0)


def test_a_handful_of_targets_takes_its_mode_as_it_is():
    # Three vehicles taking twice the kinematic time: too few for a significance test, so the
    # mode stands as long as it stands above the background.
    speeds = np.array([20.0, 25.0, 30.0])
    starts = np.array([0.0, 5.0, 10.0])
    d = Detections.from_columns(
        np.repeat([0.0, 100.0], 3),
        np.tile(speeds, 2),
        np.concatenate([starts, starts + 2.0 * 100.0 / speeds]),
    )
    model = segment_prior(arrange(d, PARAMS), 3, PARAMS)
    assert model.log_bias[0, 1] == pytest.approx(np.log(2.0), abs=PRIOR_BINS[1] - PRIOR_BINS[0])


def test_the_other_terms_start_from_the_sensors_and_the_parameters():
    d = slow_zone(2, n=60)
    s = arrange(d, PARAMS)
    model = segment_prior(s, 3, PARAMS)
    assert model.log_bias.shape == (4, 4) and model.max_span == 3
    medians = s.median_speed
    assert model.log_speed_ratio[0, 2] == pytest.approx(np.log(medians[2] / medians[0]))
    assert model.log_speed_ratio[3, 1] == 0.0  # no segment after the last sensor
    assert np.all(model.skew == KINEMATIC_SKEW)
    assert np.all(model.time_spread == PARAMS.travel_time_spread)
    # A speed changes more over more sensors: the spread grows as the square root of the span.
    np.testing.assert_allclose(
        model.speed_spread[0], PARAMS.velocity_change_spread * np.sqrt([1, 1, 2, 3])
    )
    assert model.features is None  # these detectors report no lane, length or class


def test_bins_count_as_numpy_does_and_ignore_values_out_of_range():
    rng = np.random.default_rng(3)
    values = rng.uniform(PRIOR_BINS[0], PRIOR_BINS[-1], 1000)
    expected, _ = np.histogram(values, PRIOR_BINS)
    np.testing.assert_array_equal(bin_counts(values), expected)
    outside = np.array([PRIOR_BINS[0] - 1.0, PRIOR_BINS[-1] + 1.0])
    assert bin_counts(outside).sum() == 0
    assert bin_counts(np.array([PRIOR_BINS[-1]]))[-1] == 1  # the last bin is closed


@pytest.mark.parametrize("n", [3, 10, 25, 39])
def test_segments_of_a_handful_of_targets_at_once_give_each_its_own_prior(n):
    # `few_targets_priors` works out the small samples' modes all at once, a copy of
    # `travel_time_bumps`'s path for fewer than PRIOR_TEST_SAMPLE detections: the same numbers,
    # segment by segment, whatever the sample (some slowed, some not, one sensor empty).
    rng = np.random.default_rng(n)
    noise = [  # unrelated arrivals: a mode by chance, moved by any difference in the counting
        Detections.from_columns(
            np.repeat([0.0, 150.0, 400.0], n),
            rng.uniform(5.0, 30.0, 3 * n),
            rng.uniform(0.0, 60.0, 3 * n),
        )
        for _ in range(5)
    ]
    for seed, d in enumerate([slow_zone(seed, n) for seed in range(5)] + noise):
        s = arrange(d, PARAMS)
        sensors = np.arange(s.positions.size - 1)
        samples = [s.members(p)[:: 1 + seed % 2] for p in sensors]
        samples[-1] = samples[-1][:0] if seed in (4, 9) else samples[-1]
        together = few_targets_priors(s, samples, sensors + 1)
        one_by_one = [
            travel_time_bumps(s, sample, p + 1, AssignmentParams())[0] if sample.size else 0.0
            for p, sample in zip(sensors.tolist(), samples, strict=True)
        ]
        np.testing.assert_array_equal(together, one_by_one)
        if n >= 10 and seed < 5:  # the slow zone's segment shows in both
            assert together[0] > 0.2


def test_every_segments_centre_at_once_is_each_histograms_own() -> None:
    # Segments with a few values near their peak, none, and more than run_medians takes at
    # once (then one by one): each centre is `BiasHistogram.centre`'s, to the bit.
    rng = np.random.default_rng(5)
    sizes = [7, 0, 3, 90, 12]
    values = np.concatenate([rng.normal(rng.uniform(-1, 1), 0.05, k) for k in sizes])
    value_of = np.repeat(np.arange(len(sizes)), sizes)
    excess = rng.normal(0.0, 1.0, (len(sizes), PRIOR_BINS.size - 1))
    which = np.array([0, 1, 3, 4])
    together = excess_centres(values, value_of, which, excess[which], len(sizes))
    own = np.split(values, np.cumsum(sizes)[:-1])
    alone = [BiasHistogram(own[k], excess[k], excess[k]).centre() for k in which.tolist()]
    np.testing.assert_array_equal(together, alone)


def test_arrivals_at_once_are_those_found_segment_by_segment() -> None:
    # The sample pairs' windows at the far sensors, found among every arrival at once or, where
    # a time is NaN (no arrival keys), segment by segment: the same pairs.
    s = arrange(slow_zone(3, 12), PARAMS)
    sensors = np.arange(s.positions.size - 1)
    samples = [s.members(p) for p in sensors]
    at_once = FewPairs.of(s, samples, sensors + 1)
    s.__dict__["arrival_keys"] = None  # the cached keys, as a batch with a NaN time has them
    apart = FewPairs.of(s, samples, sensors + 1)
    assert at_once.values.size > 20
    for field in ("values", "value_of", "pairs", "any_ahead"):
        np.testing.assert_array_equal(getattr(at_once, field), getattr(apart, field))
    assert at_once.rates == apart.rates and at_once.typical_sums == apart.typical_sums


def test_a_sensor_that_saw_a_vehicle_or_two_keeps_the_kinematic_prediction():
    """Its segments' pairs are almost all unrelated: the one bin its true pair falls in is as
    high as any, and a mode taken there (a travel time 6 times too long) broke every track
    through the sensor (a sensor that failed at the batch's start: 78 % -> 99.8 %)."""
    d = simulate(preset("large", n_targets=50), seed=1).detections
    third = np.flatnonzero(d.position == np.unique(d.position)[2])
    keep = np.setdiff1d(np.arange(len(d)), third[1:])  # the third sensor's first report alone
    params = AssignmentParams()
    prior = segment_prior(arrange(d.take(keep), params), params.max_skip + 1, params)
    assert prior.log_bias[1, 1] == prior.log_bias[2, 1] == 0.0


DENSE = Path(__file__).parents[3] / "data" / "sumo" / "sumo-dense.csv"


@pytest.mark.parametrize("keep", [10, 25])
def test_a_sensor_quiet_early_in_a_busy_batch_leaves_the_kinematic_prediction(keep):
    # SUMO's dense traffic (about 150 vehicles a sensor); the sixth sensor keeps its first
    # `keep` reports. Its few detections against its busy neighbour's arrivals once put its
    # segment at 6 times the kinematic travel time (keeping 25), and the links over it, whose
    # travel times add up through its median speed (that of its first vehicles), 6 % short
    # (keeping 10): every segment and every span over it is kinematic to a few per cent.
    s = arrange(sensor_cut(read_detections_csv(DENSE), 5, keep).without_labels(), PARAMS)
    assert s.sparse.nonzero()[0].tolist() == [5]
    model = segment_prior(s, 3, PARAMS)
    np.testing.assert_array_equal(model.log_bias[:-1, 1], 0.0)
    assert np.abs(model.log_bias[:-2, 2]).max() < 0.02


@pytest.mark.parametrize(("name", "n_targets", "seed"), [("large", 10, 2), ("medium", 40, 7)])
def test_a_handful_of_targets_keeps_the_kinematic_prediction_its_own_bin_holds(
    name, n_targets, seed
):
    # The paper's traffic with the third sensor quiet after half of its vehicles: the pairs of
    # vehicles that started together bunch at 4.6-5.6 times the kinematic travel time above the
    # handful of true pairs, which still stand out in the kinematic bin.
    d = simulate(preset(name, n_targets=n_targets), seed=seed).detections
    model = segment_prior(arrange(sensor_cut(d, 2, n_targets // 2), PARAMS), 3, PARAMS)
    np.testing.assert_array_equal(model.log_bias[:-1, 1], 0.0)


def test_times_stamped_in_whole_seconds_leave_short_segments_kinematic():
    # SUMO's irregular road (sensors 30 to 700 m apart) stamped in whole seconds: every travel
    # time a whole number of seconds made the histogram a comb, and a tooth of it stood out as
    # a travel time 0.75 of the kinematic one on a segment of 35 m, 1.3 s (its links priced by
    # it, 88.1 % of the detections right); spread within their second, every segment keeps the
    # kinematic prediction, as it does stamped to the hundredth.
    d = read_detections_csv(Path(__file__).parents[3] / "data" / "sumo" / "sumo-irregular.csv")
    whole = replace(d, timestamp=np.round(d.timestamp))
    prior = segment_prior(arrange(whole, PARAMS), PARAMS.max_skip + 1, PARAMS)
    np.testing.assert_array_equal(prior.log_bias[:-1, 1], 0.0)
    result = associate(whole)
    assert result.metrics is not None and result.metrics.accuracy >= 0.895
