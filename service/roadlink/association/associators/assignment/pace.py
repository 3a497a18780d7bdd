"""A track's pace read from its travel times: the evidence that survives imprecise speeds.

A loop's speed reading may be off by 5-10 %, but its timestamp is not: the time a vehicle took
over the previous segment says how fast it goes far better than either reading. Drivers hold
their pace from one segment to the next, so a link's pace (its log time per metre, relative to
its segment's typical one) is predicted by the pace of the link before it in its track. On
SUMO's dense motorway traffic that predicts a travel time to 0.5-1 % (robust spread), where the
kinematic prediction from two speed readings misses by 4-5 % at a 6 % speed error.

With exact speeds the kinematic prediction is better still (0.3-0.5 %), and the pace mostly
repeats it while it misreads every driver who brakes or overtakes: weighed in full there, the
term cost free flow 0.3 points and an irregular road 2. So it weighs by how well the speeds
are read, which the tracks themselves tell (`reading_error`): nothing below 2.5 % of error, in
full from 4 %.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.associators.assignment.arrays import filled
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import (
    MIN_RELATIVE_SPREAD,
    PACE_READING_ERROR,
    AssignmentParams,
)
from roadlink.association.associators.assignment.robust import (
    centre_and_spread,
    median,
    runs,
    spread_about,
)
from roadlink.association.associators.assignment.sensors import Sensors, travel_time
from roadlink.association.detections import FloatArray, IntArray

# The widening of a pace change's spread with the speed change read is fitted on this many
# quantiles of the speed change, each of at least this many changes.
AMBIGUITY_BINS = 5
AMBIGUITY_BIN_SIZE = 20
# The speed readings' error is a robust spread: an even sample of this many links pins it.
READING_SAMPLE = 5000


@dataclass
class PaceModel:
    """Each segment's typical log time per metre (`centre`), and how a link's pace departs from
    the pace of the link before it in its track: the median change (`shift`: slow and fast
    stretches of road) and its spread, by the later link's segment, widened by `ambiguity`
    times the speed change read (where a vehicle brakes, its pace changes); `trust` (0 to 1),
    how much the term weighs, by how well the speeds are read. Arrays are indexed [p, span]
    like the segment model's."""

    centre: FloatArray
    ambiguity: float
    shift: FloatArray
    spread: FloatArray
    trust: float

    def of(self, s: Sensors, a: IntArray, b: IntArray) -> FloatArray:
        """The relative pace of links a -> b: log time per metre minus their segment's typical."""
        p = s.sensor[a]
        span = s.sensor[b] - p
        dt = np.maximum(s.time[b] - s.time[a], 1e-9)
        dx = s.positions[s.sensor[b]] - s.positions[p]
        relative: FloatArray = np.log(dt / dx) - self.centre[p, span]
        return relative

    def segment(self, s: Sensors, a: IntArray, b: IntArray) -> tuple[FloatArray, FloatArray]:
        """The shift and spread of the pace change into links a -> b."""
        p = s.sensor[a]
        span = s.sensor[b] - p
        return self.shift[p, span], self.spread[p, span]

    def standardised(
        self, change: FloatArray, spread: FloatArray, slowing: FloatArray, noise: FloatArray
    ) -> FloatArray:
        """A pace change (its shift taken off) in units of its spread, widened by the speed
        change read and the timestamps' error."""
        return change / np.sqrt(spread**2 + (self.ambiguity * slowing) ** 2 + noise)

    def copy(self) -> PaceModel:
        return PaceModel(
            self.centre.copy(), self.ambiguity, self.shift.copy(), self.spread.copy(), self.trust
        )


@dataclass
class Neighbour:
    """The link next to candidate links in their tracks, into a (from h) or out of b (to c), as
    the pace term needs it: its relative pace (out of b, less its shift), the log speed read at
    its far end (h or c), its travel time, and, out of b, the spread of the change into it.
    NaN where a candidate's piece has no such link: it costs nothing."""

    pace: FloatArray
    speed: FloatArray
    travel: FloatArray
    spread: FloatArray

    @classmethod
    def unknown(cls, n: int) -> Neighbour:
        return cls(*(filled(n, np.nan) for _ in range(4)))

    def take(self, index: IntArray) -> Neighbour:
        return Neighbour(
            self.pace[index], self.speed[index], self.travel[index], self.spread[index]
        )


def pace_cost(
    pace: PaceModel,
    s: Sensors,
    pairs: Pairs,
    before: Neighbour,
    after: Neighbour,
    timestamp_noise: float,
) -> FloatArray:
    """-2 log density of the pace changes that each candidate link a -> b makes with the link
    into a (`before`, `incoming_pace`) and with the link out of b (`after`, `outgoing_pace`),
    weighed by the model's trust in it."""
    a, b = pairs.a, pairs.b
    here = pace.of(s, a, b)
    shift, spread = pace.segment(s, a, b)
    travel = np.maximum(s.time[b] - s.time[a], 1e-9)
    into = pace.standardised(
        here - before.pace - shift,
        spread,
        0.5 * (before.speed - s.log_speed[b]),
        _timing_noise(timestamp_noise, travel, before.travel),
    )
    out_of = pace.standardised(
        after.pace - here,
        after.spread,
        0.5 * (s.log_speed[a] - after.speed),
        _timing_noise(timestamp_noise, travel, after.travel),
    )
    return pace.trust * (_change_cost(into) + _change_cost(out_of))


def _timing_noise(timestamp_noise: float, travel: FloatArray, other: FloatArray) -> FloatArray:
    """The variance a pace change gets from the timestamps: each of the two links' log travel
    times is off by about sqrt(2) timestamp errors over its travel time."""
    noise: FloatArray = 2.0 * timestamp_noise**2 * (1.0 / travel**2 + 1.0 / other**2)
    return noise


def _change_cost(r: FloatArray) -> FloatArray:
    """-2 log of a Cauchy density of a standardised pace change, relative to its value at 0:
    2 log(1 + r^2), and 0 where there is no change to cost. Drivers hold their pace to 0.5-1 %
    most of the time and change it by 5-20 % when they change lanes, overtake or brake, a
    heavier tail than the two-component mixture of the other residuals (`model.Tails`) fits: on
    SUMO's dense traffic with a 6 % speed error the Cauchy cost gave 84.0 % against 82.6 % for
    the fitted mixture, capped at 4 or not (docs/assignment.md, "Pace")."""
    known = np.isfinite(r)
    cost = np.zeros(r.size)
    cost[known] = 2.0 * np.log1p(np.square(r[known]))
    return cost


def incoming_pace(pace: PaceModel, s: Sensors, prv: IntArray, a: IntArray) -> Neighbour:
    """The links into detections a, from their predecessors `prv` (unknown where none)."""
    into = Neighbour.unknown(a.size)
    linked = prv[a] >= 0
    h, a = prv[a[linked]], a[linked]
    into.pace[linked] = pace.of(s, h, a)
    into.speed[linked] = s.log_speed[h]
    into.travel[linked] = s.time[a] - s.time[h]
    return into


def outgoing_pace(pace: PaceModel, s: Sensors, nxt: IntArray, b: IntArray) -> Neighbour:
    """The links out of detections b, to their successors `nxt` (unknown where none)."""
    out = Neighbour.unknown(b.size)
    linked = nxt[b] >= 0
    b, c = b[linked], nxt[b[linked]]
    shift, out.spread[linked] = pace.segment(s, b, c)
    out.pace[linked] = pace.of(s, b, c) - shift
    out.speed[linked] = s.log_speed[c]
    out.travel[linked] = s.time[c] - s.time[b]
    return out


def learn_pace(
    s: Sensors,
    params: AssignmentParams,
    segments: SegmentModel,
    links: list[tuple[IntArray, IntArray]],
    prv: IntArray,
) -> PaceModel | None:
    """From the links that follow another in their track (`prv`): how far the speed readings
    are to be trusted; each segment's typical pace (its links' median, or the segment model's
    prediction at its sensors' median speeds where it has too few); how a link's pace changes
    from the one before: its widening with the speed change, and each segment's shift and
    spread. None where the speeds are trusted (the term would weigh nothing) or too few links
    follow another to tell."""
    sample = _following(links, prv, READING_SAMPLE)
    if sample[0].size < params.min_segment_samples:
        return None
    trust = _trust(reading_error(s, segments.log_speed_ratio, *sample))
    if trust == 0:
        return None
    a = np.concatenate([a for a, _ in links])
    b = np.concatenate([b for _, b in links])
    shape = segments.log_bias.shape
    model = PaceModel(
        _segment_centres(s, params, segments, a, b),
        0.0,
        np.zeros(shape),
        np.full(shape, np.inf),
        trust,
    )
    h, a, b = _following([(a, b)], prv, a.size)
    change = model.of(s, a, b) - model.of(s, h, a)
    slowing = 0.5 * (s.log_speed[h] - s.log_speed[b])  # the change the speeds would predict
    model.ambiguity = _ambiguity(change, slowing)
    noise = _timing_noise(params.timestamp_noise, s.time[b] - s.time[a], s.time[a] - s.time[h])
    p = s.sensor[a]
    _learn_changes(params, model, change, slowing, noise, p, s.sensor[b] - p)
    return model


def _following(
    links: list[tuple[IntArray, IntArray]], prv: IntArray, most: int
) -> tuple[IntArray, IntArray, IntArray]:
    """The links a -> b that follow another in their track, with the start h of the one before,
    from an even sample of at most about `most` of the links."""
    total = sum(a.size for a, _ in links)
    step = max(1, total // max(most, 1))
    a = np.concatenate([a[::step] for a, _ in links]) if links else np.zeros(0, dtype=np.int64)
    b = np.concatenate([b[::step] for _, b in links]) if links else np.zeros(0, dtype=np.int64)
    follows = prv[a] >= 0
    return prv[a[follows]], a[follows], b[follows]


def _segment_centres(
    s: Sensors, params: AssignmentParams, segments: SegmentModel, a: IntArray, b: IntArray
) -> FloatArray:
    """Every segment's log time per metre: the median of its links' where it has enough, else
    as the segment model predicts it at its sensors' median speeds."""
    log_bias, skew = segments.log_bias, segments.skew
    n, spans = log_bias.shape
    centre = np.zeros((n, spans))
    for k in range(1, spans):
        start = np.arange(max(n - k, 0))
        per_metre = travel_time(
            1.0, s.median_speed[start], s.median_speed[start + k], skew[start, k]
        )
        centre[start, k] = log_bias[start, k] + np.log(per_metre)
    p = s.sensor[a]
    span = s.sensor[b] - p
    own = np.log(
        np.maximum(s.time[b] - s.time[a], 1e-9) / (s.positions[s.sensor[b]] - s.positions[p])
    )
    for k in range(1, spans):
        of_span = span == k
        counts = np.bincount(p[of_span], minlength=n)
        segment = runs(p[of_span], counts)
        for q in np.flatnonzero(counts >= params.min_segment_samples):
            centre[q, k] = median(own[of_span][segment[q]])
    return centre


def reading_error(
    s: Sensors, log_ratio: FloatArray, h: IntArray, a: IntArray, b: IntArray
) -> float:
    """The speed readings' error (std of log), from consecutive links h -> a -> b: a reading's
    error enters the speed change before it and, with the other sign, the one after it, so
    the two changes covary by minus its variance (robust covariance from the spreads of their
    sum and difference). On SUMO traffic it reads 3.0-3.2 % at a 3 % error and 5-6 % at 6 %;
    without any, 0.7-1.5 % (the odd wrong link, read as error).

    The smaller of two readings: of the changes as they are, and of the changes about their
    segments' learned means (`log_ratio`, the segment model's log speed ratio). A sensor that
    reads every speed some per cent high or low (a loop's calibration) shifts the mean changes
    either side of it by its own bias, opposite ways, which the first takes for an error of
    every reading (every other sensor 10 % high: read as 10 %, and the pace term it turned on
    cost free flow 3 to 5 points); the second does not. But about their means, the changes of
    vehicles through a slow zone covary negatively by themselves (a driver who braked more than
    most speeds up more after), which the first, with the zone's mean changes, does not see
    (SUMO, a 50 km/h zone: 0 as they are, 3.4 % about the means; the pace term that would turn
    on cost 6.6 points)."""
    before = s.log_speed[a] - s.log_speed[h]
    after = s.log_speed[b] - s.log_speed[a]
    as_read = _covariance_error(before, after)
    about_means = _covariance_error(
        before - _mean_change(log_ratio, s, h, a), after - _mean_change(log_ratio, s, a, b)
    )
    return min(as_read, about_means)


def _covariance_error(before: FloatArray, after: FloatArray) -> float:
    covariance = (
        centre_and_spread(before + after)[1] ** 2 - centre_and_spread(before - after)[1] ** 2
    ) / 4.0
    return float(np.sqrt(max(-covariance, 0.0)))


def _mean_change(log_ratio: FloatArray, s: Sensors, a: IntArray, b: IntArray) -> FloatArray:
    p = s.sensor[a]
    return log_ratio[p, s.sensor[b] - p]


def _trust(error: float) -> float:
    """How much the pace term weighs, given the speed readings' error: nothing where speeds are
    read to a per cent or two (they predict a travel time better than the pace does, which
    then mostly repeats them), in full from a few per cent on."""
    low, high = PACE_READING_ERROR
    return float(np.clip((error - low) / (high - low), 0.0, 1.0))


def _ambiguity(change: FloatArray, slowing: FloatArray) -> float:
    """How much the spread of a pace change widens with the speed change read: the changes,
    by quantiles of |slowing|, each bin's robust variance fitted as base^2 + (k slowing)^2
    (both at least 0, by least squares); k, or 0 with too few changes."""
    size = np.abs(slowing)
    order = np.argsort(size)
    if order.size < AMBIGUITY_BINS * AMBIGUITY_BIN_SIZE:
        return 0.0
    x, y = [], []
    for chunk in np.array_split(order, AMBIGUITY_BINS):
        x.append(float(np.mean(size[chunk] ** 2)))
        y.append(centre_and_spread(change[chunk])[1] ** 2)
    slope = np.polyfit(np.asarray(x), np.asarray(y), 1)[0]
    return float(np.sqrt(max(slope, 0.0)))


def _learn_changes(
    params: AssignmentParams,
    model: PaceModel,
    change: FloatArray,
    slowing: FloatArray,
    noise: FloatArray,
    p: IntArray,
    span: IntArray,
) -> None:
    """Each segment's shift and spread of the pace change into it (before the speed change's
    and the timestamps' widening): the links that span one sensor measure their own, shrunk
    towards the pooled spread by their number; links over missed detections take the pooled
    ones."""
    pooled_shift, pooled = centre_and_spread(change)
    # Each change in units of the widening it had over the base spread pooled.
    base = max(pooled, MIN_RELATIVE_SPREAD)
    widening = np.sqrt(1.0 + ((model.ambiguity * slowing) ** 2 + noise) / base**2)
    pooled = max(spread_about(change / widening, pooled_shift), MIN_RELATIVE_SPREAD)
    model.spread[:] = pooled
    ones = span == 1
    counts = np.bincount(p[ones], minlength=model.shift.shape[0])
    segment = runs(p[ones], counts)
    for k in np.flatnonzero(counts):
        here = change[ones][segment[k]]
        w = counts[k] / (counts[k] + params.min_segment_samples)
        shift = median(here)
        own = spread_about(here / widening[ones][segment[k]], shift)
        model.shift[k, 1] = w * shift
        blended = float(np.sqrt(w * own**2 + (1 - w) * pooled**2))
        model.spread[k, 1] = max(blended, MIN_RELATIVE_SPREAD)
