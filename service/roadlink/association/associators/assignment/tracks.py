"""Tracks from links: the sequential pass that builds them sensor by sensor, and the bookkeeping
between a detection's track index and its neighbours in its track."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.anchors import Anchors, anchor_bonus
from roadlink.association.associators.assignment.arrays import filled, same
from roadlink.association.associators.assignment.costs import (
    Level,
    affordable,
    affordable_links,
    link_cost,
)
from roadlink.association.associators.assignment.edges import WindowEdges
from roadlink.association.associators.assignment.gating import (
    EverySensor,
    Gate,
    Pairs,
)
from roadlink.association.associators.assignment.matching import match, sure_matchings
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.pace import Neighbour, PaceModel
from roadlink.association.associators.assignment.params import (
    REFINE_GATE_FACTOR,
    AssignmentParams,
)
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.associators.base import Progress
from roadlink.association.detections import FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]


@dataclass
class TrackLevel:
    """Per detection: mean relative speed of its track up to and including it, and how many
    detections that mean is over; where detectors measure length, the same of its log lengths
    (a detection without a reading keeps its predecessor's); where a pace is learned, the link
    into it (`pace.Neighbour`, unknown where it starts its track)."""

    mean: FloatArray
    count: FloatArray
    length_mean: FloatArray | None = None
    length_count: FloatArray | None = None
    pace: Neighbour | None = None

    @classmethod
    def start(cls, s: Sensors, pace: PaceModel | None) -> TrackLevel:
        alone = detection_level(s, np.arange(s.time.size))
        return cls(
            alone.mean,
            alone.count,
            alone.length_mean,
            alone.length_count,
            None if pace is None else Neighbour.unknown(s.time.size),
        )

    def extend(self, s: Sensors, a: IntArray, b: IntArray, pace: PaceModel | None) -> None:
        """Detection b continues the track that ends in detection a."""
        if pace is not None and self.pace is not None:
            self.pace.pace[b] = pace.of(s, a, b)
            self.pace.speed[b] = s.log_speed[a]
            self.pace.travel[b] = s.time[b] - s.time[a]
        count = self.count[a] + 1.0
        self.mean[b] = self.mean[a] + (s.relative_speed[b] - self.mean[a]) / count
        self.count[b] = count
        if self.length_mean is None or self.length_count is None:
            return
        total = (
            self.length_mean[a] * self.length_count[a] + self.length_mean[b] * self.length_count[b]
        )
        self.length_count[b] += self.length_count[a]
        self.length_mean[b] = total / np.maximum(self.length_count[b], 1.0)

    def of(self, a: IntArray) -> Level:
        """The level of the tracks ending in detections a."""
        return Level(
            self.mean[a],
            self.count[a],
            None if self.length_mean is None else self.length_mean[a],
            None if self.length_count is None else self.length_count[a],
            None if self.pace is None else self.pace.take(a),
        )


def detection_level(s: Sensors, b: IntArray) -> Level:
    """The level of detections b, each alone (a track that starts with it)."""
    if s.features is None or not s.features.has_length():
        return Level(s.relative_speed[b], filled(b.size, 1.0))
    log_length = s.features.log_length[b]
    measured = np.isfinite(log_length)
    return Level(
        s.relative_speed[b],
        filled(b.size, 1.0),
        np.where(measured, log_length, 0.0),
        measured.astype(np.float64),
    )


def level_terms(s: Sensors) -> list[tuple[FloatArray, FloatArray]]:
    """What a piece of track averages, as (value, weight) per detection: its relative speed,
    and, where detectors measure length, its log length (weight 0 where not read)."""
    terms = [(s.relative_speed, np.ones(s.time.size))]
    if s.features is not None and s.features.has_length():
        measured = np.isfinite(s.features.log_length)
        terms.append((np.where(measured, s.features.log_length, 0.0), measured.astype(float)))
    return terms


@dataclass
class SweepSetup:
    """The re-pairing sweep's gating and window edges, worked out by a forward pass with the
    `model` the sweep may use (`associator.link_and_learn`): the pass's own are the same at a
    narrower gate, so they are taken from the sweep's (`Gate.narrowed`, `WindowEdges.each`),
    and on a paper-size batch the pass before the sweep is usually the last."""

    model: SegmentModel | None = None
    gate: Gate | None = None
    edges: WindowEdges | None = None

    def of(self, model: SegmentModel, gate: float) -> tuple[Gate, WindowEdges] | None:
        """The sweep's gating and edges for this `model` at this `gate`, if worked out."""
        if self.model is not model or self.gate is None or self.edges is None:
            return None
        return (self.gate, self.edges) if self.gate.gate == gate else None

    def forget(self) -> None:
        """Drop what was worked out, once its model will not be the sweep's: its edges are two
        numbers a detection, held through learning (the association's peak at 10^6)."""
        self.model, self.gate, self.edges = None, None, None


def build_tracks(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    leader: IntArray,
    progress: Progress | None,
    done: float,
    share: float,
    anchor: Anchors | None = None,
    sweep: SweepSetup | None = None,
    expected: IntArray | None = None,
    relay: LevelRelay | None = None,
) -> IntArray:
    """One sequential pass over the sensors: the track index of every detection (-1 = none).
    Links that lane order `anchor`s (`anchors.py`) cost their bonus less. With `sweep`, the
    re-pairing sweep's gating and edges with this model are worked out too, and kept there.
    With `expected` tracks (the round before's), the candidates and costs of every sensor are
    worked out at once as if the pass built those (`Foreseen`), as long as it does. With a
    `relay`, the pass leaves its tracks' levels there, and takes the round before's from it."""
    n_sensors = s.positions.size
    track = filled(s.time.size, -1, np.int64)
    level = TrackLevel.start(s, model.pace)
    tail = np.zeros(0, dtype=np.int64)  # last detection of every track, by track index
    if sweep is None:
        gate = Gate.of(s, model, params, params.gate_cost)
        edges = WindowEdges.of(s, model, params.gate_cost / 2.0)
    else:
        wide = Gate.of(s, model, params, REFINE_GATE_FACTOR * params.gate_cost)
        gate = wide.narrowed(params.gate_cost)
        edges, wide_edges = WindowEdges.each(s, model, (params.gate_cost / 2.0, wide.gate / 2.0))
        sweep.model, sweep.gate, sweep.edges = model, wide, wide_edges
    copies = leader if (leader >= 0).any() else None
    foreseen = None
    if expected is not None and gate.every is not None:
        foreseen = Foreseen.of(s, model, params, gate.every, edges, anchor, expected, relay)
    made: list[tuple[IntArray, IntArray]] = []  # the links made, while foreseen
    priced = None  # every link's own prices, once a sensor is linked on its own (`Priced`)
    # What an anchor can take off a link's cost at most (`costs.affordable`; inf: unknown).
    most_bonus = 0.0 if anchor is None else float(anchor.bonus.max(initial=0.0))
    most_bonus = most_bonus if np.isfinite(most_bonus) else np.inf
    for q in range(n_sensors):
        linked_b = np.zeros(0, dtype=np.int64)
        if q > 0 and tail.size:
            if foreseen is None:
                if priced is None and gate.every is not None:
                    priced = Priced.of(gate, gate.every, edges, (anchor, most_bonus))
                linked_b = _extend_tracks(
                    s,
                    model,
                    params,
                    gate,
                    edges,
                    q,
                    track,
                    tail,
                    level,
                    (anchor, most_bonus),
                    priced,
                )
            else:
                pairs, cost = foreseen.at(q)
                sure = foreseen.sure_links(q)
                linked_a, linked_b = sure or match(pairs.a, pairs.b, cost, params.gate_cost)
                track[linked_b] = track[linked_a]
                tail[track[linked_b]] = linked_b
                made.append((linked_a, linked_b))
        # Where vehicles join the road (`ends.py`), one beside a vehicle at its speed is new,
        # not a copy of that vehicle's report.
        joins = model.ends is not None and model.ends.arriving[q] > 0
        born = _births(s.members(q), linked_b, track, None if joins else copies)
        track[born] = tail.size + np.arange(born.size)
        tail = np.concatenate([tail, born])
        if foreseen is not None and not same(track[s.members(q)], foreseen.expected[s.members(q)]):
            # Not the tracks foreseen: on from here sensor by sensor, with the levels of the
            # tracks made so far.
            foreseen = None
            for a, b in made:
                level.extend(s, a, b, model.pace)
        if progress:
            progress(done + share * (q + 1) / n_sensors)
    if relay is not None:
        # A pass that built the tracks foreseen extended no level (and ends the rounds); only
        # a pass gated at once can foresee, so only there are the levels held on (at 10^6
        # detections they would be held through the next pass).
        done_alone = foreseen is None and gate.every is not None
        relay.track, relay.level = (track, level) if done_alone else (None, None)
    return track


@dataclass
class LevelRelay:
    """A forward pass's tracks and their levels (`TrackLevel`), for the next round's pass that
    foresees those tracks (`Foreseen`): a level's mean speeds and lengths along a track depend
    on the track alone, not on the model, so they are taken as they are (one pass's extends
    sensor by sensor, where Foreseen would make them again); the pace, the model's, is worked
    out again, for every link at once."""

    track: IntArray | None = None
    level: TrackLevel | None = None

    def levels(
        self, s: Sensors, expected: IntArray, prv: IntArray, pace: PaceModel | None
    ) -> TrackLevel | None:
        """The levels of the `expected` tracks (whose predecessors are `prv`) with this `pace`,
        if the pass that built them left them here."""
        if self.track is not expected or self.level is None:
            return None
        neighbour = None
        if pace is not None:
            # What `TrackLevel.extend` writes, for every link at once (each number its own).
            neighbour = Neighbour.unknown(s.time.size)
            b = (prv >= 0).nonzero()[0]
            a = prv[b]
            neighbour.pace[b] = pace.of(s, a, b)
            neighbour.speed[b] = s.log_speed[a]
            neighbour.travel[b] = s.time[b] - s.time[a]
        kept = self.level
        return TrackLevel(kept.mean, kept.count, kept.length_mean, kept.length_count, neighbour)


@dataclass(frozen=True)
class Foreseen:
    """A forward pass's candidate links into every sensor and their costs, worked out at once as
    if the pass built the `expected` tracks: on a paper-size batch the second round builds the
    first round's tracks, and numpy's fixed costs of each sensor's gating and costs, some fifty
    calls, were most of a pass. As long as the pass has built those tracks, sensor q sees
    those tracks' ends before it (its open tails, by track index, `_extend_tracks`) and their
    levels, so its candidates and their costs are these, each candidate's numbers its own
    (`build_tracks` checks the tracks sensor by sensor, and goes on without these at the first
    that differs)."""

    expected: IntArray
    pairs: Pairs
    cost: FloatArray
    bounds: list[int]  # sensor q's candidates are pairs[bounds[q]:bounds[q + 1]]
    chosen: BoolArray  # the candidates that are links of the expected tracks
    sure: list[bool]  # whether sensor q's matching surely makes those (`sure_matchings`)

    @classmethod
    def of(
        cls,
        s: Sensors,
        model: SegmentModel,
        params: AssignmentParams,
        every: EverySensor,
        edges: WindowEdges,
        anchor: Anchors | None,
        expected: IntArray,
        relay: LevelRelay | None = None,
    ) -> Foreseen:
        nxt, prv = successors(s, expected)
        gated = every.pairs
        a, b = gated.a, gated.b
        q = s.sensor[b]
        # The open tails before sensor q: a track's last detection before it, within reach
        # (every gated link is); by track index, as `EverySensor.into` orders them.
        keep = (expected[a] >= 0) & ((nxt[a] < 0) | (s.sensor[np.maximum(nxt[a], 0)] >= q))
        kept = keep.nonzero()[0]
        key = q[kept] * (int(expected.max(initial=0)) + 1) + expected[a[kept]]
        pairs = gated.take(kept[key.argsort(kind="stable")])
        level = None if relay is None else relay.levels(s, expected, prv, model.pace)
        if level is None:
            level = TrackLevel.start(s, model.pace)
            for sensor in range(1, s.positions.size):
                m = s.members(sensor)
                m = m[prv[m] >= 0]
                level.extend(s, prv[m], m, model.pace)
        cost = link_cost(params, model, pairs, level.of(pairs.a), detection_level(s, pairs.b), s)
        if anchor is not None:  # else a bonus of 0, which changes no cost
            cost -= anchor_bonus(pairs, anchor)
        cost += edges.cost(pairs)
        q = s.sensor[pairs.b]
        bounds = q.searchsorted(np.arange(s.positions.size + 1))
        chosen = (nxt[pairs.a] == pairs.b) & (cost < params.gate_cost)  # what match could take
        sure = sure_matchings(pairs.a, pairs.b, cost, q, chosen, params.gate_cost, s.positions.size)
        return cls(expected, pairs, cost, bounds.tolist(), chosen, sure.tolist())

    def at(self, q: int) -> tuple[Pairs, FloatArray]:
        """Sensor q's candidates and their costs."""
        lo, hi = self.bounds[q], self.bounds[q + 1]
        return self.pairs.part(lo, hi), self.cost[lo:hi]

    def sure_links(self, q: int) -> tuple[IntArray, IntArray] | None:
        """The links sensor q's matching makes, where it surely makes the expected tracks' (the
        same set as `match` returns; the pass uses them in no order): None where unsure."""
        if not self.sure[q]:
            return None
        lo, hi = self.bounds[q], self.bounds[q + 1]
        linked = self.chosen[lo:hi]
        return self.pairs.a[lo:hi][linked], self.pairs.b[lo:hi][linked]


@dataclass(frozen=True)
class Priced:
    """What a forward pass's links cost besides their tracks' terms, for every link gated at
    once (`EverySensor`): whether it is `affordable` (`costs.affordable_links`; None: every
    one), the window's `edges` and the anchor's `bonus` (None: no anchors). Each is a link's
    own, so worked out once for the pass: the same numbers as sensor by sensor, where numpy's
    fixed cost of a dozen calls a sensor was the work."""

    every: EverySensor
    affordable: BoolArray | None
    edges: FloatArray
    bonus: FloatArray | None

    @classmethod
    def of(
        cls,
        gate: Gate,
        every: EverySensor,
        edges: WindowEdges,
        anchors: tuple[Anchors | None, float],
    ) -> Priced:
        """The prices of the links `gate` gated at once (`every`, its `Gate.every`)."""
        anchor, most_bonus = anchors
        own = every.pairs.own_cost(gate.model, gate.params)
        usable = affordable_links(gate.params, gate.model, own, gate.s, most_bonus)
        bonus = None if anchor is None else anchor_bonus(every.pairs, anchor)
        return cls(every, usable, edges.cost(every.pairs), bonus)

    def add_to(self, cost: FloatArray, place: IntArray) -> None:
        """Add to the costs of the links at `place` what `_extend_tracks` adds (less an
        anchor's bonus, which is 0 without anchors: subtracting 0 changes no number)."""
        if self.bonus is not None:
            cost -= self.bonus[place]
        cost += self.edges[place]


def _extend_tracks(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    gate: Gate,
    edges: WindowEdges,
    q: int,
    track: IntArray,
    tail: IntArray,
    level: TrackLevel,
    anchors: tuple[Anchors | None, float],
    priced: Priced | None = None,
) -> IntArray:
    """Link the open tracks (those whose last detection lies within `max_skip` missed sensors)
    to sensor q's detections, one to one at least cost; the detections linked. A link pays for
    the window's edges (`edges.WindowEdges`); an anchored one costs its bonus less (`anchors`:
    the anchors, and their largest bonus). With `priced` (every sensor's links gated at once),
    the candidates and what their costs add for the edges and anchors are taken from there."""
    anchor, most_bonus = anchors
    open_tails = tail[s.sensor[tail] >= q - 1 - params.max_skip]
    if priced is None:
        pairs = gate.pairs(open_tails, q)
        if pairs.a.size:
            # Links that cost at least the gate whatever their other terms: the matching drops
            # them.
            pairs = affordable(params, model, pairs, s, most_bonus)
        place = None
    else:
        place = priced.every.places(q, open_tails, usable=priced.affordable)
        pairs = priced.every.pairs.take(place)
    if not pairs.a.size:
        return np.zeros(0, dtype=np.int64)
    a, b = pairs.a, pairs.b
    cost = link_cost(params, model, pairs, level.of(a), detection_level(s, b), s)
    if priced is None or place is None:
        cost -= anchor_bonus(pairs, anchor)
        cost += edges.cost(pairs)
    else:
        priced.add_to(cost, place)
    linked_a, linked_b = match(a, b, cost, params.gate_cost)
    level.extend(s, linked_a, linked_b, model.pace)
    track[linked_b] = track[linked_a]
    tail[track[linked_b]] = linked_b
    return linked_b


def _births(
    members: IntArray, linked_b: IntArray, track: IntArray, leader: IntArray | None
) -> IntArray:
    """The detections of a sensor that start tracks: the unmatched ones, except a report that may
    duplicate one just linked (same sensor, moments apart, same speed): one passage reported
    twice must not start a second track. Two such reports both unmatched both start tracks,
    since they may be two vehicles side by side; a copy's track then dies short
    (`min_track_length`). `leader` None: no report may duplicate another."""
    unmatched = members[track[members] < 0]
    if leader is None:
        return unmatched
    twin_linked = np.zeros(track.size, dtype=bool)
    copies = linked_b[leader[linked_b] >= 0]
    twin_linked[leader[copies]] = True
    lead = leader[unmatched]
    twin_linked[unmatched[lead >= 0]] |= track[lead[lead >= 0]] >= 0
    return unmatched[~twin_linked[unmatched]]


def successors(s: Sensors, track: IntArray) -> tuple[IntArray, IntArray]:
    """The next and previous detection of every detection in its track (-1 = none)."""
    n = track.size
    nxt = filled(n, -1, np.int64)
    prv = filled(n, -1, np.int64)
    assigned = (track >= 0).nonzero()[0]
    chain = s.by_track(assigned, track)
    same = track[chain[1:]] == track[chain[:-1]]
    nxt[chain[:-1][same]] = chain[1:][same]
    prv[chain[1:][same]] = chain[:-1][same]
    return nxt, prv


def tracks_from_links(s: Sensors, prv: IntArray, in_track: BoolArray) -> IntArray:
    """Track index of every detection from its predecessor links (-1 where not in a track)."""
    track = filled(prv.size, -1, np.int64)
    count = 0
    for k in range(s.positions.size):
        members = s.members(k)
        members = members[in_track[members]]
        linked = prv[members] >= 0
        track[members[linked]] = track[prv[members[linked]]]
        first = members[~linked]
        track[first] = count + np.arange(first.size)
        count += first.size
    return track
