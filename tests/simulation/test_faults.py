"""The fault model that both simulators share."""

from __future__ import annotations

import numpy as np
import pytest

import roadlink.simulation.generate as paper
import roadlink.simulation.sumo.runner as sumo_runner
from roadlink.association.detections import CLUTTER
from roadlink.simulation import preset, simulate
from roadlink.simulation.faults import DetectorFaults, Passages, apply_detector_faults
from roadlink.simulation.sumo import with_detector_faults

N = 20_000


def _passages(n: int = N) -> Passages:
    rng = np.random.default_rng(7)
    return Passages(
        sensor=np.repeat([0, 1], n // 2),
        time=np.tile(np.linspace(100.0, 700.0, n // 2), 2),
        speed=rng.uniform(20.0, 30.0, n),
        target=np.tile(np.arange(n // 2), 2),
    )


def _constant(speed: float):
    return lambda _k, count, _seen, _rng: np.full(count, speed)


def test_no_faults_leave_the_passages_as_they_were():
    clean = _passages()
    out = apply_detector_faults(
        clean,
        DetectorFaults(),
        np.random.default_rng(0),
        false_alarm_speeds=_constant(1.0),
        clutter=-1,
    )
    for column in ("sensor", "time", "speed", "target"):
        assert np.array_equal(getattr(out, column), getattr(clean, column))


def test_each_fault_happens_at_its_rate_and_false_alarms_are_labelled_clutter():
    faults = DetectorFaults(miss_probability=0.2, duplicate_probability=0.1, false_alarm_rate=0.05)
    out = apply_detector_faults(
        _passages(),
        faults,
        np.random.default_rng(1),
        false_alarm_speeds=_constant(99.0),
        clutter=-1,
        false_alarm_margin=5.0,
    )
    real = out.target >= 0
    kept = np.unique(out.target[real] * 2 + out.sensor[real]).size
    assert kept / N == pytest.approx(0.8, abs=0.02)  # misses
    assert real.sum() / kept == pytest.approx(1.1, abs=0.02)  # duplicates of what was kept
    alarms = ~real
    assert alarms.sum() / real.sum() == pytest.approx(0.05, abs=0.01)
    assert set(out.speed[alarms]) == {99.0}  # the caller's false-alarm speeds
    assert out.time[alarms].min() < 100.0 and out.time[alarms].max() > 700.0  # the margin
    assert out.time[alarms].min() >= 95.0 and out.time[alarms].max() <= 705.0


def test_noise_is_multiplicative_on_speed_and_additive_on_time():
    faults = DetectorFaults(velocity_noise=0.05, timestamp_noise=0.1)
    clean = _passages()
    out = apply_detector_faults(
        clean, faults, np.random.default_rng(2), false_alarm_speeds=_constant(1.0), clutter=-1
    )
    assert np.std(np.log(out.speed / clean.speed)) == pytest.approx(0.05, rel=0.05)
    assert np.std(out.time - clean.time) == pytest.approx(0.1, rel=0.05)


def test_a_speed_bias_is_one_factor_a_sensor():
    clean = Passages(
        sensor=np.repeat(np.arange(400), 5),
        time=np.tile(np.arange(5.0), 400),
        speed=np.full(2000, 25.0),
        target=np.tile(np.arange(5), 400),
    )

    def faulty(**faults: float) -> Passages:
        return apply_detector_faults(
            clean,
            DetectorFaults(**faults),
            np.random.default_rng(3),
            false_alarm_speeds=_constant(1.0),
            clutter=-1,
        )

    log_factor = np.log(faulty(velocity_bias=0.1, timestamp_noise=0.1).speed / 25.0)
    per_sensor = log_factor.reshape(400, 5)
    assert np.ptp(per_sensor, axis=1).max() < 1e-12  # every speed of a sensor alike
    assert np.std(per_sensor[:, 0]) == pytest.approx(0.1, rel=0.1)
    assert np.array_equal(faulty(velocity_bias=0.0).speed, clean.speed)


def _with_features(passages: Passages) -> Passages:
    n = passages.time.size
    vehicle = passages.target % 3  # three kinds of vehicle, one lane each
    return (
        passages.replace(
            lane=vehicle.astype(np.int64),
            length=np.array([4.0, 8.0, 15.0])[vehicle],
            vehicle_class=np.array(["car", "van", "truck"], dtype=object)[vehicle],
        )
        if n
        else passages
    )


def test_length_noise_is_multiplicative_and_features_follow_their_passage():
    clean = _with_features(_passages())
    faults = DetectorFaults(length_noise=0.07, duplicate_probability=0.2, miss_probability=0.1)
    out = apply_detector_faults(
        clean, faults, np.random.default_rng(3), false_alarm_speeds=_constant(1.0), clutter=-1
    )
    true_length = np.array([4.0, 8.0, 15.0])[out.target % 3]
    assert np.std(np.log(out.length / true_length)) == pytest.approx(0.07, rel=0.05)
    assert np.array_equal(out.lane, out.target % 3)  # duplicates keep their passage's lane
    assert np.array_equal(out.vehicle_class, np.array(["car", "van", "truck"])[out.target % 3])


def test_false_alarms_read_features_their_sensor_reported_and_none_where_it_reported_none():
    with_features = _with_features(_passages())
    faults = DetectorFaults(false_alarm_rate=0.1)
    out = apply_detector_faults(
        with_features,
        faults,
        np.random.default_rng(4),
        false_alarm_speeds=_constant(1.0),
        clutter=-1,
    )
    alarms = out.target < 0
    assert set(out.lane[alarms]) == {0, 1, 2}
    assert set(out.length[alarms]) == {4.0, 8.0, 15.0}
    assert set(out.vehicle_class[alarms]) == {"car", "van", "truck"}
    plain = apply_detector_faults(
        _passages(), faults, np.random.default_rng(4), false_alarm_speeds=_constant(1.0), clutter=-1
    )
    assert (plain.lane == -1).all() and np.isnan(plain.length).all()
    assert set(plain.vehicle_class) == {None}


def test_both_simulators_draw_their_faults_through_the_shared_model(monkeypatch):
    seen: list[DetectorFaults] = []

    def spy(passages, faults, rng, **how):
        seen.append(faults)
        return apply_detector_faults(passages, faults, rng, **how)

    monkeypatch.setattr(paper, "apply_detector_faults", spy)
    monkeypatch.setattr(sumo_runner, "apply_detector_faults", spy)
    faults = DetectorFaults(miss_probability=0.3, false_alarm_rate=0.1)
    simulated = simulate(preset("medium", **faults.model_dump()), seed=4).detections
    with_detector_faults(simulated, faults, np.random.default_rng(9))
    assert seen == [faults, faults]
    assert CLUTTER in set(simulated.target.tolist())
