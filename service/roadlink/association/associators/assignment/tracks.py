"""Tracks from links: the sequential pass that builds them sensor by sensor, and the bookkeeping
between a detection's track index and its neighbours in its track."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.anchors import Anchors, anchor_bonus
from roadlink.association.associators.assignment.costs import Level, affordable, link_cost
from roadlink.association.associators.assignment.edges import WindowEdges
from roadlink.association.associators.assignment.gating import Gate
from roadlink.association.associators.assignment.matching import match
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.pace import Neighbour, PaceModel
from roadlink.association.associators.assignment.params import AssignmentParams
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
        return Level(s.relative_speed[b], np.ones(b.size))
    log_length = s.features.log_length[b]
    measured = np.isfinite(log_length)
    return Level(
        s.relative_speed[b],
        np.ones(b.size),
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


def duplicate_followers(s: Sensors, params: AssignmentParams) -> IntArray:
    """For every detection, the earlier report of the same sensor it may duplicate (-1 if none):
    within `duplicate_window` in time and `duplicate_velocity_tolerance` in speed."""
    n = s.time.size
    leader = np.full(n, -1, dtype=np.int64)
    if params.duplicate_window <= 0:
        return leader
    tolerance = np.log1p(params.duplicate_velocity_tolerance)
    for k in range(s.positions.size):
        m = s.members(k)
        for lag in range(1, m.size):
            later, earlier = m[lag:], m[:-lag]
            close = s.time[later] - s.time[earlier] <= params.duplicate_window
            if not close.any():
                break
            alike = close & (np.abs(s.log_speed[later] - s.log_speed[earlier]) <= tolerance)
            fresh = alike & (leader[later] < 0)
            leader[later[fresh]] = earlier[fresh]
    return leader


def build_tracks(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    leader: IntArray,
    progress: Progress | None,
    done: float,
    share: float,
    anchor: Anchors | None = None,
) -> IntArray:
    """One sequential pass over the sensors: the track index of every detection (-1 = none).
    Links that lane order `anchor`s (`anchors.py`) cost their bonus less."""
    n_sensors = s.positions.size
    track = np.full(s.time.size, -1, dtype=np.int64)
    level = TrackLevel.start(s, model.pace)
    tail = np.zeros(0, dtype=np.int64)  # last detection of every track, by track index
    gate = Gate.of(s, model, params, params.gate_cost)
    edges = WindowEdges.of(s, model, params.gate_cost / 2.0)
    copies = leader if (leader >= 0).any() else None
    # What an anchor can take off a link's cost at most (`costs.affordable`; inf: unknown).
    most_bonus = 0.0 if anchor is None else float(anchor.bonus.max(initial=0.0))
    most_bonus = most_bonus if np.isfinite(most_bonus) else np.inf
    for q in range(n_sensors):
        linked_b = np.zeros(0, dtype=np.int64)
        if q > 0 and tail.size:
            linked_b = _extend_tracks(
                s, model, params, gate, edges, q, track, tail, level, (anchor, most_bonus)
            )
        born = _births(s.members(q), linked_b, track, copies)
        track[born] = tail.size + np.arange(born.size)
        tail = np.concatenate([tail, born])
        if progress:
            progress(done + share * (q + 1) / n_sensors)
    return track


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
) -> IntArray:
    """Link the open tracks (those whose last detection lies within `max_skip` missed sensors)
    to sensor q's detections, one to one at least cost; the detections linked. A link pays for
    the window's edges (`edges.WindowEdges`); an anchored one costs its bonus less (`anchors`:
    the anchors, and their largest bonus)."""
    anchor, most_bonus = anchors
    open_tails = tail[s.sensor[tail] >= q - 1 - params.max_skip]
    pairs = gate.pairs(open_tails, q)
    if pairs.a.size:
        # Links that cost at least the gate whatever their other terms: the matching drops them.
        pairs = affordable(params, model, pairs, s, most_bonus)
    if not pairs.a.size:
        return np.zeros(0, dtype=np.int64)
    a, b = pairs.a, pairs.b
    cost = link_cost(params, model, pairs, level.of(a), detection_level(s, b), s)
    cost -= anchor_bonus(pairs, anchor)
    cost += edges.cost(pairs)
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
    nxt = np.full(n, -1, dtype=np.int64)
    prv = np.full(n, -1, dtype=np.int64)
    assigned = np.flatnonzero(track >= 0)
    chain = s.by_track(assigned, track)
    same = track[chain[1:]] == track[chain[:-1]]
    nxt[chain[:-1][same]] = chain[1:][same]
    prv[chain[1:][same]] = chain[:-1][same]
    return nxt, prv


def tracks_from_links(s: Sensors, prv: IntArray, in_track: BoolArray) -> IntArray:
    """Track index of every detection from its predecessor links (-1 where not in a track)."""
    track = np.full(prv.size, -1, dtype=np.int64)
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
