"""Candidate links and what their cost needs: the pairs a gate in time lets through."""

from __future__ import annotations

import itertools
from dataclasses import dataclass, fields

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.arrays import filled
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import FASTEST_SHARE, AssignmentParams
from roadlink.association.associators.assignment.sensors import Sensors, travel_time
from roadlink.association.associators.assignment.silences import over_silence
from roadlink.association.detections import FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]


@dataclass
class Pairs:
    """Candidate links a -> b with what their cost needs: the standardised travel-time error, the
    unexplained log speed change, the segment's speed spread, and the number of sensors spanned;
    and, where a pass worked it out for all its links at once, what each costs on its own
    (`own_cost`).
    """

    a: IntArray
    b: IntArray
    r_time: FloatArray
    ratio: FloatArray
    speed_spread: FloatArray
    span: IntArray
    own: FloatArray | None = None

    def take(self, keep: BoolArray | IntArray) -> Pairs:
        if keep.dtype == np.bool_:
            # The places once, then a gather per array: a mask's selection from every array
            # costs about twice as much where the mask follows no pattern (a gate's).
            keep = np.flatnonzero(keep)
        return Pairs(
            self.a[keep],
            self.b[keep],
            self.r_time[keep],
            self.ratio[keep],
            self.speed_spread[keep],
            self.span[keep],
            None if self.own is None else self.own[keep],
        )

    def part(self, lo: int, hi: int) -> Pairs:
        """Pairs lo to hi (views)."""
        return Pairs(
            self.a[lo:hi],
            self.b[lo:hi],
            self.r_time[lo:hi],
            self.ratio[lo:hi],
            self.speed_spread[lo:hi],
            self.span[lo:hi],
            None if self.own is None else self.own[lo:hi],
        )

    @classmethod
    def concatenate(cls, parts: list[Pairs]) -> Pairs:
        own = [p.own for p in parts if p.own is not None]
        return cls(
            **{
                field.name: np.concatenate([getattr(p, field.name) for p in parts])
                for field in fields(cls)
                if field.name != "own"  # which some parts may lack
            },
            own=np.concatenate(own) if len(own) == len(parts) else None,
        )

    def own_cost(self, model: SegmentModel, params: AssignmentParams) -> FloatArray:
        """The terms of `costs.link_cost` that depend on the link alone, not on the tracks it
        joins: the travel-time error's cost plus the weighed speed change's."""
        if self.own is not None:
            return self.own
        time_cost = model.time_tails.cost(self.r_time)
        speed_cost = model.speed_tails.cost(self.ratio / self.speed_spread)
        return time_cost + params.velocity_change_weight * speed_cost

    @classmethod
    def none(cls) -> Pairs:
        empty = np.zeros(0, dtype=np.int64)
        nothing = np.zeros(0)
        return cls(empty, empty, nothing, nothing, nothing, empty)

    @classmethod
    def between(
        cls, s: Sensors, model: SegmentModel, params: AssignmentParams, a: IntArray, b: IntArray
    ) -> Pairs:
        """The given links, whatever sensors they join."""
        p = s.sensor[a]
        span = s.sensor[b] - p
        length = np.exp(model.log_bias[p, span]) * (s.positions[s.sensor[b]] - s.positions[p])
        r_time, ratio = time_residual(
            params,
            travel_time(length, s.speed[a], s.speed[b], model.skew[p, span]),
            s.time[b] - s.time[a],
            s.log_speed[b] - s.log_speed[a] - model.log_speed_ratio[p, span],
            model.time_spread[p, span],
        )
        return cls(a, b, r_time, ratio, model.speed_spread[p, span], span)


def time_residual(
    params: AssignmentParams,
    predicted: FloatArray,
    travel: FloatArray,
    ratio: FloatArray,
    time_spread: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Standardised error of a travel time against the segment's prediction from both ends'
    speeds (`predicted`, see SegmentModel). The unexplained speed change `ratio` widens the
    spread: where between the sensors the speed changed is unknown, so the travel time is too."""
    return standardised(params, predicted, travel, ratio, time_spread * time_spread), ratio


def standardised(
    params: AssignmentParams,
    predicted: FloatArray,
    travel: FloatArray,
    ratio: FloatArray,
    time_variance: FloatArray,
) -> FloatArray:
    """`time_residual`'s standardised error, given the square of the relative time spread:
    (travel - predicted) / sqrt((relative * predicted)^2 + 2 noise^2), where relative =
    sqrt(time_spread^2 + (ambiguity * ratio)^2), worked out in place."""
    spread = params.velocity_change_ambiguity * ratio
    np.multiply(spread, spread, out=spread)
    np.add(time_variance, spread, out=spread)
    np.sqrt(spread, out=spread)  # relative
    np.multiply(spread, predicted, out=spread)  # absolute
    np.multiply(spread, spread, out=spread)
    np.add(spread, 2.0 * params.timestamp_noise**2, out=spread)
    np.sqrt(spread, out=spread)
    error = np.subtract(travel, predicted)
    np.divide(error, spread, out=error)
    return error


@dataclass
class Departures:
    """What the links from detections a towards sensor q need of a, worked out once per a.

    `sensors.travel_time` is split in two here: each pair's prediction is from_a + to_b / v_b,
    the part a's own speed explains and the part b's speed will."""

    a: IntArray
    span: IntArray
    from_a: FloatArray
    to_b: FloatArray
    centre: FloatArray  # the log speed expected at q
    time_spread: FloatArray
    speed_spread: FloatArray

    @classmethod
    def towards(cls, s: Sensors, model: SegmentModel, a: IntArray, q: int | IntArray) -> Departures:
        p = s.sensor[a]
        span = q - p
        length = np.exp(model.log_bias[p, span]) * (s.positions[q] - s.positions[p])
        w = model.skew[p, span]
        return cls(
            a,
            span,
            length * (1.0 - w) / s.speed[a],
            length * w,
            s.log_speed[a] + model.log_speed_ratio[p, span],
            model.time_spread[p, span],
            model.speed_spread[p, span],
        )

    def part(self, lo: int, hi: int) -> Departures:
        """Departures lo to hi."""
        return Departures(*(getattr(self, field.name)[lo:hi] for field in fields(self)))


# Candidates gated at once: their dozen temporary arrays stay in a core's cache (a call at 10^6
# detections has about 150,000, 1.2 MB an array). 32768 gated 10^6 detections' passes about 5 %
# quicker than 16384 (fewer numpy calls), 8192 10 % slower.
GATE_CHUNK = 32768

# Up to this many detections per sensor, the links into every sensor are gated in one pass
# (`EverySensor`): on a paper-size batch (10 a sensor) numpy's fixed cost per call, not the
# links, is the work (12 % less time); from 30-40 a sensor on, gating every detection towards
# every sensor in reach costs more than the calls it saves.
GATE_AT_ONCE = 20


def gated_pairs(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    a: IntArray,
    q: int,
    gate: float,
    among: BoolArray | None = None,
) -> Pairs:
    """Candidate links from detections a to sensor q whose travel time alone is within the gate
    (to those of sensor q's detections that are `among`, where given).

    The time window first allows any speed seen at q (sorted times, `searchsorted`), so the work
    is proportional to the detections near each one, never to all pairs; then, with b's speed
    known, pairs whose travel time alone costs more than the gate are dropped. Pairs come by a,
    in the order given, then by b's time."""
    lo_index, hi_index = int(s.start[q]), int(s.start[q + 1])
    if hi_index == lo_index or a.size == 0:
        return Pairs.none()
    slot = np.arange(lo_index, hi_index)  # sensor q's detections by time, as places in s.order
    if among is not None:
        slot = slot[among[s.order[lo_index:hi_index]]]
        if slot.size == 0:
            return Pairs.none()
    d = Departures.towards(s, model, a, q)
    inverse_q = s.sorted_inverse_speed[lo_index:hi_index]
    fastest, slowest = float(inverse_q.min()), float(inverse_q.max())
    lo, hi = _arrival_window(s, model, params, d, q, gate, fastest, slowest)
    if among is None:
        # Sensor q's places are one run: a candidate's place is its rank beyond the run's first.
        times = s.sorted_time[lo_index:hi_index]
        first = np.searchsorted(times, lo, side="left")
        count = np.maximum(np.searchsorted(times, hi, side="right") - first, 0)
        return _within_gate(s, model, params, d, None, first + lo_index, count, gate)
    times = s.sorted_time[slot]
    first = np.searchsorted(times, lo, side="left")
    count = np.maximum(np.searchsorted(times, hi, side="right") - first, 0)
    return _within_gate(s, model, params, d, slot, first, count, gate)


def _within_gate(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    d: Departures,
    slot: IntArray | None,
    first: IntArray,
    count: IntArray,
    gate: float,
) -> Pairs:
    """The links from each of d's departures to `count` places of `slot` (places in s.order;
    None: the places themselves) from its `first` on, those whose travel time alone is within
    the gate: GATE_CHUNK candidates at a time (or the departures of one that has more)."""
    ends = count.cumsum()
    if ends.size == 0 or ends[-1] <= GATE_CHUNK:
        return _within_gate_chunk(s, model, params, d, slot, first, count, gate)
    cuts = np.searchsorted(ends, np.arange(GATE_CHUNK, ends[-1], GATE_CHUNK), side="right")
    cuts = np.unique(np.concatenate([[0], cuts, [ends.size]]))
    return Pairs.concatenate(
        [
            _within_gate_chunk(
                s, model, params, d.part(lo, hi), slot, first[lo:hi], count[lo:hi], gate
            )
            for lo, hi in itertools.pairwise(cuts.tolist())
        ]
    )


def _within_gate_chunk(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    d: Departures,
    slot: IntArray | None,
    first: IntArray,
    count: IntArray,
    gate: float,
) -> Pairs:
    """`_within_gate` of one chunk."""
    which = np.arange(d.a.size).repeat(count)  # the departure of every candidate
    at = (first - (count.cumsum() - count)).repeat(count)
    at += np.arange(which.size)
    if slot is not None:
        at = slot[at]
    # A departure's numbers repeated for each of its candidates (np.repeat: quicker than
    # indexing by `which`, the same numbers).
    predicted = d.to_b.repeat(count)
    predicted *= s.sorted_inverse_speed[at]
    np.add(d.from_a.repeat(count), predicted, out=predicted)
    travel = s.sorted_time[at]
    travel -= s.time[d.a].repeat(count)
    ratio = s.sorted_log_speed[at]
    ratio -= d.centre.repeat(count)
    variance = (d.time_spread * d.time_spread).repeat(count)
    r_time = standardised(params, predicted, travel, ratio, variance)
    within = model.time_tails.within(r_time, d.span.repeat(count), params.miss_cost, gate)
    keep = within.nonzero()[0]  # once: quicker than the mask for each array (`Pairs.take`)
    kept = which[keep]
    b = s.order[at[keep]]
    span = d.span[kept]
    if span.size and span.max() > 1:
        heard = ~over_silence(s, d.a[kept], b, span)
        keep, kept, b, span = keep[heard], kept[heard], b[heard], span[heard]
    return Pairs(d.a[kept], b, r_time[keep], ratio[keep], d.speed_spread[kept], span)


def _arrival_window(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    d: Departures,
    q: int | IntArray,
    gate: float,
    fastest: float | FloatArray,
    slowest: float | FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Earliest and latest time at sensor q of a link from each of d's detections within the
    gate: at any speed seen at q (`fastest` and `slowest`, inverse speeds), the gate's number of
    spreads, the widest ambiguity."""
    reach = model.time_tails.reach(gate)
    worst = np.maximum(np.abs(-np.log(fastest) - d.centre), np.abs(-np.log(slowest) - d.centre))
    relative = np.sqrt(d.time_spread**2 + (params.velocity_change_ambiguity * worst) ** 2)
    slack = reach * params.timestamp_noise * np.sqrt(2.0)
    t_a = s.time[d.a]
    lo = t_a + (d.from_a + d.to_b * fastest) * np.exp(-reach * relative) - slack
    # However heavy the tails, no target covers the gap much faster than the fastest speed
    # either sensor measured: such a link is two targets' detections, never one target's.
    p = s.sensor[d.a]
    gap = s.positions[q] - s.positions[p]
    quickest = gap / (FASTEST_SHARE * np.maximum(s.top_speed[p], s.top_speed[q]))
    # Nor before a's own time, however wide the timestamps' slack grows with the gate (or with a
    # feature's bonus, which widens the gate): a vehicle reaches the next sensor after it.
    lo = np.maximum(lo, t_a + np.maximum(quickest - slack, 0.0))
    hi = t_a + (d.from_a + d.to_b * slowest) * (1.0 + reach * relative) + slack
    return lo, hi


@dataclass
class EverySensor:
    """The candidate links of every detection to each of the `max_skip + 1` sensors after it,
    gated at once (by arrival sensor, then departure as in s.order, then b's time): what
    `gated_pairs` gives, link by link, since every number of a link is its own."""

    pairs: Pairs
    bounds: IntArray  # the links into sensor q are pairs[bounds[q]:bounds[q + 1]]
    detections: int

    @classmethod
    def gate(
        cls, s: Sensors, model: SegmentModel, params: AssignmentParams, gate: float
    ) -> EverySensor:
        n, n_sensors = s.time.size, s.positions.size
        a, q = s.reaching(params.max_skip + 1)
        d = Departures.towards(s, model, a, q)
        fastest, slowest = _inverse_speed_range(s)
        lo, hi = _arrival_window(s, model, params, d, q, gate, fastest[q], slowest[q])
        first, count = _arrivals_between(s, q, lo, hi)
        pairs = _within_gate(s, model, params, d, None, first, count, gate)
        # Each link's own cost, once for the pass (numpy's fixed cost per call, not the links,
        # is a paper-size batch's work: a dozen calls for every sensor otherwise).
        pairs.own = pairs.own_cost(model, params)
        return cls(pairs, s.sensor[pairs.b].searchsorted(np.arange(n_sensors + 1)), n)

    def narrowed(
        self, s: Sensors, model: SegmentModel, params: AssignmentParams, gate: float
    ) -> EverySensor | None:
        """What `gate` with a narrower `gate` gives, from these links (gated with this `model`
        at a wider gate): those within the narrower gate's arrival windows (`searchsorted`'s
        left at lo and right at hi: lo <= time <= hi) and within the gate itself, in the same
        order, each with the same numbers (every number of a link is its own). A wider gate's
        windows hold the narrower's, and its links those of any narrower gate. None where a
        window's end is NaN (`searchsorted` and a comparison differ there)."""
        pairs = self.pairs
        q = s.sensor[pairs.b]
        d = Departures.towards(s, model, pairs.a, q)
        fastest, slowest = _inverse_speed_range(s)
        lo, hi = _arrival_window(s, model, params, d, q, gate, fastest[q], slowest[q])
        if np.isnan(hi).any():
            return None
        arrival = s.time[pairs.b]
        keep = model.time_tails.within(pairs.r_time, pairs.span, params.miss_cost, gate)
        keep &= lo <= arrival
        keep &= arrival <= hi
        kept = pairs.take(keep)
        bounds = s.sensor[kept.b].searchsorted(np.arange(s.positions.size + 1))
        return EverySensor(kept, bounds, self.detections)

    def into(self, q: int, a: IntArray, among: BoolArray | None = None) -> Pairs:
        """`gated_pairs` from detections a (within reach of q) to sensor q (to those `among`)."""
        place = self.places(q, a, among)
        return self.pairs.take(place) if place.size else Pairs.none()

    def places(
        self, q: int, a: IntArray, among: BoolArray | None = None, usable: BoolArray | None = None
    ) -> IntArray:
        """Where `into`'s links lie in `pairs`, in its order; only `usable` ones, where given."""
        lo, hi = int(self.bounds[q]), int(self.bounds[q + 1])
        rank = filled(self.detections, -1, np.int64)
        rank[a] = np.arange(a.size)
        order = rank[self.pairs.a[lo:hi]]
        keep = order >= 0
        if among is not None:
            keep &= among[self.pairs.b[lo:hi]]
        if usable is not None:
            keep &= usable[lo:hi]
        kept = keep.nonzero()[0]
        place: IntArray = lo + kept[order[kept].argsort(kind="stable")]
        return place

    def across(self, k: int, end: int, tails: IntArray, among: BoolArray) -> Pairs:
        """`into(q, tails, among)` for every q from k to end - 1, one after another, where the
        `tails` lie before sensor k in s.order's order: the links into those sensors are already
        by departure in that order, so they are one run of `pairs`, filtered."""
        lo, hi = int(self.bounds[k]), int(self.bounds[end])
        is_tail = np.zeros(self.detections, dtype=bool)
        is_tail[tails] = True
        keep = is_tail[self.pairs.a[lo:hi]] & among[self.pairs.b[lo:hi]]
        return self.pairs.take(lo + keep.nonzero()[0])


def _inverse_speed_range(s: Sensors) -> tuple[FloatArray, FloatArray]:
    """Each sensor's least and greatest inverse speed: its fastest and its slowest."""
    return (
        np.minimum.reduceat(s.sorted_inverse_speed, s.start[:-1]),
        np.maximum.reduceat(s.sorted_inverse_speed, s.start[:-1]),
    )


def _arrivals_between(
    s: Sensors, q: IntArray, lo: FloatArray, hi: FloatArray
) -> tuple[IntArray, IntArray]:
    """For each window [lo, hi] at sensor q: the place in s.order of its first arrival, and how
    many arrive within it; `searchsorted` in each sensor's times (left at lo, right at hi), for
    every sensor at once by one stable sort of the arrivals and the window's ends together, keyed
    by (sensor, time, lo before an equal time, hi after it): each end's place among the sorted
    arrivals is the number of arrivals before it."""
    keys = s.arrival_keys
    if keys is not None:
        # The same places by one binary search each among the arrivals as (sensor, time),
        # which are sorted so (a third of the sort's time on a paper-size batch).
        ends = np.empty((2, q.size), dtype=np.complex128)
        ends.real = q
        ends.imag[0] = lo
        ends.imag[1] = hi
        if not np.isnan(ends.imag).any():
            first = keys.searchsorted(ends[0], side="left")
            last = keys.searchsorted(ends[1], side="right")
            return first, np.maximum(last - first, 0)
    n, m = s.time.size, q.size
    sensor = np.concatenate([s.sensor[s.order], q, q])
    time = np.concatenate([s.sorted_time, lo, hi])
    side = np.repeat(np.array([1, 0, 2], dtype=np.int8), [n, m, m])
    merged = np.lexsort((side, time, sensor))
    arrival = merged < n
    place = np.empty(n + 2 * m, dtype=np.int64)
    place[merged] = np.cumsum(arrival) - arrival  # the arrivals before each
    first = place[n : n + m]
    return first, np.maximum(place[n + m :] - first, 0)


@dataclass
class Gate:
    """`gated_pairs` with the model and gate of one pass over the sensors: sensor by sensor, or,
    with few detections a sensor (GATE_AT_ONCE), from every sensor's links gated at once."""

    s: Sensors
    model: SegmentModel
    params: AssignmentParams
    gate: float
    every: EverySensor | None = None

    @classmethod
    def of(cls, s: Sensors, model: SegmentModel, params: AssignmentParams, gate: float) -> Gate:
        if s.time.size > GATE_AT_ONCE * s.positions.size:
            return cls(s, model, params, gate)
        return cls(s, model, params, gate, EverySensor.gate(s, model, params, gate))

    def narrowed(self, gate: float) -> Gate:
        """This pass's gating at a narrower `gate`: from this one's links where they were gated
        at once (`EverySensor.narrowed`), else anew."""
        every = None
        if self.every is not None:
            every = self.every.narrowed(self.s, self.model, self.params, gate)
            if every is None:
                return Gate.of(self.s, self.model, self.params, gate)
        return Gate(self.s, self.model, self.params, gate, every)

    def pairs(self, a: IntArray, q: int, among: BoolArray | None = None) -> Pairs:
        """`gated_pairs(s, model, params, a, q, gate, among)`, a within reach of q."""
        if self.every is None:
            return gated_pairs(self.s, self.model, self.params, a, q, self.gate, among)
        return self.every.into(q, a, among)

    def across(self, k: int, tails: IntArray, among: BoolArray) -> Pairs:
        """The links from `tails` (detections before sensor k, in s.order's order) to those
        `among` the detections of sensors k to k + max_skip: `pairs` from the tails within reach
        of each sensor, sensor after sensor (at once, from every sensor's links gated at once)."""
        reach = self.params.max_skip + 1
        end = min(k + reach, self.s.positions.size)
        if self.every is not None:
            return self.every.across(k, end, tails, among)
        sensor = self.s.sensor[tails]
        return Pairs.concatenate(
            [self.pairs(tails[sensor >= q - reach], q, among) for q in range(k, end)]
        )
