"""Lane-order anchors: links that a lane's order makes sure of, in queues above all.

A vehicle that keeps its lane between two sensors cannot pass another that keeps it too: lane by
lane, traffic is first in, first out, and two vehicles that follow each other in a lane take
about the same time over the segment (in a queue both crawl in the same wave; in free flow both
keep about the same speed, so the error of the kinematic prediction barely changes). Where
detectors report lanes, each lane's detections at two neighbouring sensors are aligned in time
order as one chain (`smooth_chain`), scored as a log likelihood ratio: each pair by its lengths
(where both were measured) and, loosely, its kinematic travel time; each step from one pair to
the next by the change of travel time, against a spread each segment learns from its own chains
(`learned_smoothness`: a queue's followers differ more than free flow's). A stretch of pairs
shifted by a vehicle must skip a vehicle or jump in travel time at each end where the true
alignment flows on, so the chain's links are right far more often than the sparse assignment's
in a queue (where a travel time of a hundred headways cannot tell neighbours apart), and about
as often elsewhere. They cover only the vehicles that keep their lane, and they are evidence,
not commands: from the second linking round on, an anchored link costs less in the forward pass
(`build_tracks`) and in the re-pairing sweeps (`refine_boundaries`), by as much as its chain
beat the rivals that shift it (`chain_margins`), weighed by how often its segment's tracks built
without anchors contradict its anchors (`weigh_anchors`). See docs/assignment.md (Lane order).
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass

import numpy as np

from roadlink.association.associators.assignment.chains import (
    STEP_TAIL,
    ChainProblem,
    chains_with_margins,
)
from roadlink.association.associators.assignment.features import (
    FeatureModel,
    length_density_at,
)
from roadlink.association.associators.assignment.first_chains import (
    Terms,
    batches,
    kinematic_gain,
    learned_smoothnesses,
    loose_chains,
    recentred,
)
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import NO_LANE, FloatArray, IntArray

# A pair without both lengths (detectors that report lane alone) is pinned by time alone, so a
# chain shifted by a vehicle scores nearly as well as the true one: measured on SUMO queues and
# slow zones (lane alone against lane and length), such an anchor is right as often as one with
# lengths of this share of its margin.
LANE_ONLY_MARGIN = 0.65
# No vehicle passes at more than this multiple of the fastest speed either sensor measured.
TOP_SPEED_MARGIN = 2.0
# An anchored link's cost (-2 log density) is lowered by this much (odds of e^8): an anchor
# decides unless speeds and times speak clearly against it.
ANCHOR_BONUS = 16.0
# The share of a segment's anchors that the tracks built without them contradict, at and above
# which the anchors weigh in full (see `weigh_anchors`). The chains are wrong for up to about
# 15 % of what they link where vehicles change lanes often, so a disagreement of that much says
# little about the tracks; several times more says that the tracks are what is lost.
FULL_DISAGREEMENT = 0.4
# Upstream detections per block of a lane's chain (see `_blocks`).
BLOCK = 500
# The least and greatest chance of a detection skipped in a lane's chain (`skip_costs`): a
# detector misses a few percent of the vehicles whatever the lanes do, and a chain that skips
# freely is no chain. On the 29 SUMO scenarios with lane, length and class, (0.05, 0.6) and
# (0.03, 0.9) scored within 0.02 points of these.
SKIP_CHANCES = (0.03, 0.6)


@dataclass
class Anchors:
    """Each detection's anchored predecessor (-1 = none), and what an anchored link into it
    saves in cost."""

    predecessor: IntArray
    bonus: FloatArray
    # How much each segment's anchors weigh (by the sensor it starts at): 0 where its tracks
    # agree with them, 1 where they disagree on FULL_DISAGREEMENT or more (`weigh_anchors`).
    weight: FloatArray | None = None

    def weighed_segments(self, s: Sensors) -> IntArray:
        """The segments (by the sensor they start at) where some anchor carries a bonus."""
        weighed = self.predecessor[self.bonus > 0]
        return np.unique(s.sensor[weighed])


def anchor_bonus(pairs: Pairs, anchors: Anchors | None) -> FloatArray:
    """What each candidate link's cost loses for being anchored (nothing if not). An anchor is
    evidence, not a command: where speeds and times tell vehicles apart, a wrong anchor still
    costs more than the true link; where they cannot (a queue), it decides."""
    if anchors is None:
        return np.zeros(pairs.a.size)
    return np.where(anchors.predecessor[pairs.b] == pairs.a, anchors.bonus[pairs.b], 0.0)


def weigh_anchors(
    s: Sensors, predecessor: IntArray, margin: FloatArray, track: IntArray
) -> Anchors:
    """Each anchor's bonus: its chain's margin over the best rival (`chain_margins`; in cost
    units, -2 log, at most ANCHOR_BONUS), weighed by how often, in its segment, the tracks
    built without anchors disagree with them: in free flow the two agree on nearly every link,
    and where they do not, it is as often the lane order that is wrong (a lane changer); in a
    queue they disagree on a third or more, and there the tracks are what is lost. The weight
    grows with the share of disagreement, to 1 at FULL_DISAGREEMENT.

    Lanes must be the road's lanes, numbered alike at every sensor: where they are labels that
    keep no order (the paper's simulation with `--lanes`), the anchors are mostly wrong, the
    tracks contradict them everywhere, and only the speeds and times overrule them (docs/
    assignment.md measures what that costs)."""
    bonus = np.zeros(predecessor.size)
    anchored = np.flatnonzero(predecessor >= 0)
    if not anchored.size:
        return Anchors(predecessor, bonus)
    a = predecessor[anchored]
    agree = (track[a] >= 0) & (track[a] == track[anchored])
    segment = s.sensor[a]
    count = np.bincount(segment, minlength=s.positions.size)
    disagree = np.bincount(segment, ~agree, minlength=s.positions.size) / np.maximum(count, 1)
    share = np.minimum(disagree / FULL_DISAGREEMENT, 1.0)
    sure = np.minimum(2.0 * margin[anchored], ANCHOR_BONUS)
    bonus[anchored] = sure * share[segment]
    return Anchors(predecessor, bonus, share)


@dataclass
class Chains:
    """Lanes' chains: each detection's anchored predecessor at the sensor before (-1 = none),
    by how much its chain beat the best rival there (`chain_margins`, log likelihood), and each
    segment's learned smoothness (`learned_smoothness`; by the sensor it starts at, NaN where no
    chain was drawn)."""

    predecessor: IntArray
    margin: FloatArray
    smoothness: FloatArray


def lane_order_anchors(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    track: IntArray | None = None,
    drawn: Chains | None = None,
    segments: Iterable[int] | None = None,
) -> Chains:
    """Every lane's chains between neighbouring sensors; none where detectors do not report
    lanes. A pair without both lengths is weighed by time alone, its margin discounted to
    LANE_ONLY_MARGIN.

    Without tracks, a pair's lengths are its two readings. With a `track` for every detection,
    they are the means of the readings along the track up to a and from b on (`track_lengths`):
    a vehicle read at several sensors is told from its neighbours by far more than one reading
    can tell (cars' lengths differ by about twice a loop's error). Chains `drawn` before lend
    their segments' smoothness, and only the `segments` named (the sensors they start at; all by
    default) are drawn."""
    n_segments = s.positions.size - 1
    chains = Chains(
        np.full(s.time.size, -1, dtype=np.int64),
        np.zeros(s.time.size),
        np.full(max(n_segments, 0), np.nan),
    )
    f = s.features
    if f is None or model.features is None or not f.has_lane():
        return chains
    lengths = track_lengths(s, track)
    blocks = {
        k: _segment_blocks(s, model, k)
        for k in (range(n_segments) if segments is None else segments)
    }
    for group in batches(list(blocks), lambda k: sum(a.size * b.size for a, b, _ in blocks[k])):
        terms = {
            k: [
                (*_pair_terms(s, model, params, k, a, b, longest, lengths), a, b)
                for a, b, longest in blocks[k]
            ]
            for k in group
        }
        skips = {k: [skip_costs(s, model, k, a, b) for a, b, _ in blocks[k]] for k in group}
        _draw_segments(s, params, terms, chains, drawn, skips)
    return chains


def skip_costs(
    s: Sensors, model: SegmentModel, k: int, a: IntArray, b: IntArray
) -> tuple[float, float]:
    """What skipping a detection costs in the chain of one lane's block `a` (at sensor k) into
    the lane of `b` (at k + 1): -log of the chance, by the segment's learned lane transitions,
    that a vehicle of a's lane does not reach b's lane (a row skipped), and that a vehicle
    reaching b's lane came from another lane (a column skipped), each within SKIP_CHANCES.

    A skip is a lane changer (or a detection whose partner a detector missed), and how many
    change lanes differs by segment: few where the lanes run on, one in five or more at a merge.
    A chain shifted by a vehicle pays one skip where it shifts and one where it comes back, so a
    fixed cost let the chains of segments where hardly anyone changes lanes slip by a vehicle
    around the few who did, and charged the chains of merges for every merger."""
    f, features = s.features, model.features
    assert f is not None and features is not None
    transition = features.lane_transition[k, 1]
    lane, destination = int(f.lane[a[0]]), int(f.lane[b[0]])
    upstream = f.lane[s.members(k)]
    counts = np.bincount(upstream[upstream != NO_LANE], minlength=transition.shape[0])
    arrivals = counts * transition[:, destination]
    total = float(arrivals.sum())
    from_elsewhere = (total - float(arrivals[lane])) / total if total > 0 else 1.0
    leave = 1.0 - float(transition[lane, destination])
    row_chance, column_chance = np.clip([leave, from_elsewhere], *SKIP_CHANCES)
    return -float(np.log(row_chance)), -float(np.log(column_chance))


def _draw_segments(
    s: Sensors,
    params: AssignmentParams,
    terms: Terms,
    chains: Chains,
    drawn: Chains | None,
    skips: dict[int, list[tuple[float, float]]],
) -> None:
    """Draw the chains of the segments of `terms` (each block's pair terms and its detections
    upstream and downstream, by segment) into `chains`: their smoothness (learned, or lent by
    the chains `drawn` before), then every block's chain and margins, in runs of blocks drawn at
    once (`first_chains.batches`)."""
    assert s.features is not None
    measured = np.isfinite(s.features.log_length)
    # Without lengths, time alone pins a chain: a wide step would let it slip by a vehicle.
    tail = {
        k: STEP_TAIL if measured[s.members(k)].any() and measured[s.members(k + 1)].any() else 0.0
        for k in terms
    }
    lent = {
        k: float(drawn.smoothness[k])
        for k in terms
        if drawn is not None and np.isfinite(drawn.smoothness[k])
    }
    # Each block's first chain, drawn loose once: where lengths pin the chains, it centres
    # the kinematic term (`recentred`), and it teaches the smoothness.
    loose = loose_chains(
        terms, [(k, i) for k in terms if tail[k] > 0 for i in range(len(terms[k]))], tail, skips
    )
    unlearned = {k: [t[:3] for t in terms[k]] for k in terms if k not in lent}
    smoothness = lent | learned_smoothnesses(unlearned, tail, loose)
    terms = recentred(s, params, terms, loose)
    for k in terms:
        chains.smoothness[k] = smoothness[k]
    problems = [
        (ChainProblem(gain, log_travel, kinematic, smoothness[k], tail[k], *skip), a, b)
        for k in terms
        for (gain, log_travel, kinematic, a, b), skip in zip(terms[k], skips[k], strict=True)
    ]
    for run in batches(problems, lambda p: p[0].gain.size):
        drawn_run = chains_with_margins([problem for problem, _, _ in run])
        for (_, a, b), (pairs, margins) in zip(run, drawn_run, strict=True):
            if not pairs:
                continue
            i, j = np.array(pairs).T
            timed_only = ~(measured[a[i]] & measured[b[j]])
            margin = np.where(timed_only, LANE_ONLY_MARGIN * margins, margins)
            # Lanes that merge share the lane they reach (`lane_destinations`), and blocks
            # overlap: a detection keeps the surest of the chains that pair it.
            better = (chains.predecessor[b[j]] < 0) | (margin > chains.margin[b[j]])
            chains.predecessor[b[j[better]]] = a[i[better]]
            chains.margin[b[j[better]]] = margin[better]


def _segment_blocks(
    s: Sensors, model: SegmentModel, k: int
) -> list[tuple[IntArray, IntArray, float]]:
    """Every lane's blocks (`_blocks`) of detections at sensors k and k + 1: each lane at k
    with the lane at k + 1 that most of its vehicles reach (`lane_destinations`)."""
    f = s.features
    assert f is not None
    up, down = s.members(k), s.members(k + 1)
    blocks = []
    for lane, destination in lane_destinations(s, model, k).items():
        blocks.extend(_blocks(s, k, up[f.lane[up] == lane], down[f.lane[down] == destination]))
    return blocks


def lane_destinations(s: Sensors, model: SegmentModel, k: int) -> dict[int, int]:
    """Each lane reported at sensor k, and the lane at k + 1 that its vehicles reach most often
    by the segment's learned lane transitions (`features.learn_features`): its own, unless most
    leave it. Where the road narrows, the lanes that end merge into those that go on, and where
    numbering restarts (a lane drop on the left, numbered from the right, or the reverse) the
    same lane goes on under another number; each lane's order still holds in the lane it
    reaches (on SUMO's lane drops, 60-100 % of a segment's vehicles there change their lane's
    number, and a chain of one lane number had nothing to align)."""
    f, features = s.features, model.features
    assert f is not None and features is not None
    up_lanes = np.unique(f.lane[s.members(k)])
    down_lanes = np.unique(f.lane[s.members(k + 1)])
    down_lanes = down_lanes[down_lanes != NO_LANE]
    destinations = {}
    for lane in up_lanes[up_lanes != NO_LANE].tolist():
        if not down_lanes.size:
            break
        reach = features.lane_transition[k, 1, lane, down_lanes]
        destinations[lane] = int(down_lanes[int(np.argmax(reach))])
    return destinations


def _blocks(
    s: Sensors, k: int, up: IntArray, down: IntArray
) -> list[tuple[IntArray, IntArray, float]]:
    """A lane's detections at sensors k and k + 1 (in time order) in blocks of at most BLOCK
    upstream detections, each with the downstream detections its vehicles can reach: the
    chain's work and memory grow with the block, never with the day. A chain breaks at a
    block's edge, so a few links there are left to the assignment. With each block, the
    longest travel time a vehicle can take: twice the gap at the slowest speed either sensor
    measured in the lane."""
    gap = s.positions[k + 1] - s.positions[k]
    slowest = min(s.speed[up].min(initial=np.inf), s.speed[down].min(initial=np.inf))
    longest = TOP_SPEED_MARGIN * gap / slowest if np.isfinite(slowest) else 0.0
    blocks = []
    for first in range(0, up.size, BLOCK):
        a = up[first : first + BLOCK]
        reach = (s.time[down] > s.time[a[0]]) & (s.time[down] <= s.time[a[-1]] + longest)
        if reach.any():
            blocks.append((a, down[reach], longest))
    return blocks


def _pair_terms(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    k: int,
    a: IntArray,
    b: IntArray,
    longest: float,
    lengths: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Every pair's gain, its log travel time and its kinematic error (log travel time against
    the gap at the mean speed). The gain is the pair's length likelihood ratio (where both
    lengths were measured) and its kinematic error's log density
    (`first_chains.kinematic_gain`); -inf where faster than any vehicle or slower than `longest`
    (which keeps each row's chain to a band of columns)."""
    assert s.features is not None and model.features is not None
    gap = s.positions[k + 1] - s.positions[k]
    shortest = gap / (TOP_SPEED_MARGIN * max(s.top_speed[k], s.top_speed[k + 1]))
    travel = s.time[b][None, :] - s.time[a][:, None]
    possible = (travel > shortest) & (travel <= longest)
    with np.errstate(divide="ignore", invalid="ignore"):
        log_travel = np.where(possible, np.log(travel), np.nan)
    speed = 0.5 * (s.speed[a][:, None] + s.speed[b][None, :])
    kinematic = log_travel - np.log(gap / speed)
    gain = kinematic_gain(s, params, a, b, kinematic)
    prefix_mean, prefix_count, suffix_mean, suffix_count = lengths
    length_a, length_b = prefix_mean[a], suffix_mean[b]
    measured_a, measured_b = prefix_count[a] > 0, suffix_count[b] > 0
    if measured_a.any() and measured_b.any():
        # The difference of two means carries both their errors.
        length_spread = model.features.length_spread * np.sqrt(
            1.0 / np.maximum(prefix_count[a], 1.0)[:, None]
            + 1.0 / np.maximum(suffix_count[b], 1.0)[None, :]
        )
        length = _length_gain(
            np.where(measured_a, length_a, 0.0),
            np.where(measured_b, length_b, 0.0),
            length_spread,
            model.features,
            k + 1,
        )
        gain += np.where(measured_a[:, None] & measured_b[None, :], length, 0.0)
    return np.where(possible, gain, -np.inf), log_travel, kinematic


def track_lengths(
    s: Sensors, track: IntArray | None
) -> tuple[FloatArray, FloatArray, FloatArray, FloatArray]:
    """Each detection's mean log length over its track up to and including it, and the number
    of readings in that mean; then the same from it to the track's end. Without tracks (and for
    a detection in none), its own reading alone (0 readings where it measured none)."""
    assert s.features is not None
    measured = np.isfinite(s.features.log_length)
    reading = np.where(measured, s.features.log_length, 0.0)
    count = measured.astype(np.float64)
    if track is None:
        return reading, count, reading, count
    # Along each track in road order, then against it: running sums restarted at every track.
    forwards = np.lexsort((s.sensor, track))
    forwards = forwards[track[forwards] >= 0]
    means = []
    for order in (forwards, forwards[::-1]):
        total, readings = reading.copy(), count.copy()
        total[order] = _running_sums(reading[order], track[order])
        readings[order] = _running_sums(count[order], track[order])
        means += [total / np.maximum(readings, 1.0), readings]
    return means[0], means[1], means[2], means[3]


def _running_sums(values: FloatArray, key: IntArray) -> FloatArray:
    """Cumulative sums of `values`, restarted wherever `key` changes."""
    total = np.cumsum(values)
    start = np.flatnonzero(np.r_[True, key[1:] != key[:-1]])
    before = np.r_[0.0, total][start]
    counts = np.diff(np.r_[start, key.size])
    result: FloatArray = total - np.repeat(before, counts)
    return result


def _length_gain(
    length_a: FloatArray,
    length_b: FloatArray,
    spread: FloatArray | float,
    features: FeatureModel,
    sensor_b: int,
) -> FloatArray:
    """The log-likelihood ratio of every pair's two log lengths (rows a, columns b): one
    vehicle read twice (a normal difference of `spread`), against b any vehicle that b's sensor
    sees (its length density)."""
    difference = length_b[None, :] - length_a[:, None]
    same = -0.5 * (difference / spread) ** 2 - np.log(spread * np.sqrt(2.0 * np.pi))
    density = length_density_at(features, sensor_b, length_b)
    gain: FloatArray = same - np.log(density)[None, :]
    return gain
