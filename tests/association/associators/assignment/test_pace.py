"""A track's pace read from its travel times (`assignment/pace.py`): the speed readings' error
learned from the tracks, the model learned only where speeds are read poorly, and a link that
keeps its track's pace costing less than one that breaks it."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.learning import span_links
from roadlink.association.associators.assignment.pace import (
    Neighbour,
    PaceModel,
    incoming_pace,
    learn_pace,
    outgoing_pace,
    pace_cost,
    reading_error,
)
from roadlink.association.associators.assignment.sensors import Sensors, arrange
from roadlink.association.associators.assignment.tracks import successors
from roadlink.association.detections import Detections
from tests.association.associators.assignment.roads import kinematic_model

PARAMS = AssignmentParams()
POSITIONS = np.arange(0.0, 2000.0, 250.0)  # 8 sensors


def wandering_vehicles(
    n: int, reading_error: float, seed: int = 0
) -> tuple[Detections, np.ndarray]:
    """n vehicles a second apart at 25-35 m/s, each one's pace wandering by 0.5 % from one
    segment to the next, their speeds read with a log-normal `reading_error`; with the true
    track index of every detection."""
    rng = np.random.default_rng(seed)
    speed = rng.uniform(25.0, 35.0, n)
    time = np.arange(n, dtype=float) + rng.uniform(0.0, 0.3, n)
    positions, velocities, timestamps, tracks = [], [], [], []
    for k, x in enumerate(POSITIONS):
        if k:
            speed = speed * np.exp(rng.normal(0.0, 0.005, n))
            time = time + (x - POSITIONS[k - 1]) / speed
        positions.append(np.full(n, x))
        velocities.append(speed * np.exp(rng.normal(0.0, reading_error, n)))
        timestamps.append(time.copy())
        tracks.append(np.arange(n))
    d = Detections.from_columns(
        position=np.concatenate(positions),
        velocity=np.concatenate(velocities),
        timestamp=np.concatenate(timestamps),
    )
    return d, np.concatenate(tracks)


def true_links(s: Sensors, track: np.ndarray) -> tuple[list[tuple[np.ndarray, ...]], np.ndarray]:
    """The links of the true tracks, as learning takes them, and every detection's predecessor."""
    chain = np.lexsort((s.sensor, track))
    links = [span_links(s, track, chain, 1)]
    return links, successors(s, track)[1]


def learned(reading: float, n: int = 120) -> tuple[Sensors, np.ndarray, PaceModel | None]:
    d, track = wandering_vehicles(n, reading)
    s = arrange(d, PARAMS)
    links, prv = true_links(s, track)
    return s, track, learn_pace(s, PARAMS, kinematic_model(POSITIONS.size, PARAMS), links, prv)


@pytest.mark.parametrize("error", [0.03, 0.06, 0.10])
def test_the_reading_error_is_read_off_consecutive_speed_changes(error):
    d, track = wandering_vehicles(300, error)
    s = arrange(d, PARAMS)
    ((a, b),) = true_links(s, track)[0]
    prv = successors(s, track)[1]
    follows = prv[a] >= 0
    no_change = np.zeros((POSITIONS.size, 2))
    estimate = reading_error(s, no_change, prv[a[follows]], a[follows], b[follows])
    assert estimate == pytest.approx(error, rel=0.2)


@pytest.mark.parametrize("error", [0.0, 0.06])
def test_a_sensors_calibration_is_no_reading_error(error):
    """Every other sensor reads every speed 10 % high: the speed changes either side of it
    shift opposite ways by its bias, which read as they are look like a 10 % error of every
    reading. About their segments' mean changes, the readings' own error is what is read."""
    d, track = wandering_vehicles(300, error)
    calibration = np.where(np.searchsorted(POSITIONS, d.position) % 2 == 0, 1.1, 1.0)
    s = arrange(dataclasses.replace(d, velocity=d.velocity * calibration), PARAMS)
    ((a, b),) = true_links(s, track)[0]
    no_change = np.zeros((POSITIONS.size, 2))
    mean_change = no_change.copy()
    change = s.log_speed[b] - s.log_speed[a]
    for p in range(POSITIONS.size - 1):
        mean_change[p, 1] = np.median(change[s.sensor[a] == p])
    prv = successors(s, track)[1]
    follows = prv[a] >= 0
    h, a, b = prv[a[follows]], a[follows], b[follows]
    assert reading_error(s, no_change, h, a, b) > 0.08 + error / 2  # as read
    assert reading_error(s, mean_change, h, a, b) == pytest.approx(error, abs=0.015)


def test_exact_speeds_are_trusted_and_no_pace_is_learned():
    assert learned(0.0)[2] is None


def test_poorly_read_speeds_give_a_pace_in_full_trust():
    _, _, pace = learned(0.06)
    assert pace is not None
    assert pace.trust == 1.0
    # The pace wanders by 0.5 % a segment; the spread is floored at a per cent (MIN_PACE_SPREAD)
    # and must not take the 6 % reading error for the pace's.
    inner = pace.spread[1:-1, 1]
    assert (inner < 0.02).all()


def test_a_link_that_keeps_the_pace_costs_less_than_one_to_the_next_vehicle():
    s, track, pace = learned(0.06)
    assert pace is not None
    nxt, prv = successors(s, track)
    # Every detection at the fourth sensor, linked on to its own successor and to the one of
    # the vehicle a second behind it.
    a = s.members(3)
    own = nxt[a]
    order = np.argsort(s.time[own])
    other = own[np.roll(order, -1)][np.argsort(order)]  # the next vehicle's detection
    model = kinematic_model(POSITIONS.size, PARAMS)
    model.pace = pace

    def cost(b: np.ndarray) -> np.ndarray:
        pairs = Pairs.between(s, model, PARAMS, a, b)
        before = incoming_pace(pace, s, prv, a)
        return pace_cost(pace, s, pairs, before, Neighbour.unknown(a.size), 0.02)

    assert np.mean(cost(own) < cost(other)) > 0.95
    # Out of b, too: the true successor's own next link keeps the pace.
    pairs = Pairs.between(s, model, PARAMS, a, own)
    after = outgoing_pace(pace, s, nxt, own)
    alone = pace_cost(pace, s, pairs, Neighbour.unknown(a.size), Neighbour.unknown(a.size), 0.02)
    both = pace_cost(pace, s, pairs, Neighbour.unknown(a.size), after, 0.02)
    assert (alone == 0).all() and np.median(both) < 2.0


def test_the_cost_is_the_trust_times_a_cauchy_density():
    s, track, pace = learned(0.06)
    assert pace is not None
    nxt, prv = successors(s, track)
    a = s.members(3)
    model = kinematic_model(POSITIONS.size, PARAMS)
    pairs = Pairs.between(s, model, PARAMS, a, nxt[a])
    before = incoming_pace(pace, s, prv, a)
    full = pace_cost(pace, s, pairs, before, Neighbour.unknown(a.size), 0.0)
    pace.trust = 0.25
    quarter = pace_cost(pace, s, pairs, before, Neighbour.unknown(a.size), 0.0)
    np.testing.assert_allclose(quarter, 0.25 * full)
    # A change of r spreads costs 2 log(1 + r^2): 10 spreads cost about 9, not 100.
    shift, spread = pace.segment(s, a, nxt[a])
    r = (pace.of(s, a, nxt[a]) - before.pace - shift) / np.sqrt(
        spread**2 + (pace.ambiguity * 0.5 * (before.speed - s.log_speed[nxt[a]])) ** 2
    )
    np.testing.assert_allclose(full, 2.0 * np.log1p(r**2), rtol=1e-9)
