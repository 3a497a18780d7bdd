"""Lane-order anchors: links that a lane's order makes sure of, in queues above all.

A vehicle that keeps its lane between two sensors cannot pass another that keeps it too: lane by
lane, traffic is first in, first out, and two vehicles that follow each other in a lane take
about the same time over the segment (in a queue both crawl in the same wave; in free flow both
keep about the same speed, so the error of the kinematic prediction barely changes). Where
detectors report lane and length, each lane's detections at two neighbouring sensors are
aligned in time order as one chain (`smooth_chain`): each pair scores its length likelihood
ratio, each step from one pair to the next the change of travel time. A stretch of pairs
shifted by a vehicle must jump in travel time twice where the true alignment flows on, so the
chain's links are right far more often than the sparse assignment's in a queue (where a
travel time of a hundred headways cannot tell neighbours apart), and about as often elsewhere.
They cover only the vehicles that keep their lane, and they are evidence, not commands: from the
second linking round on, an anchored link costs less in the forward pass (`build_tracks`) and
in the re-pairing sweeps (`refine_boundaries`), by a bonus that each segment earns by how often
the tracks built without anchors contradict its anchors (`weigh_anchors`). See
docs/assignment.md (Lane order).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.associators.assignment.features import (
    FeatureModel,
    length_density_at,
)
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import NO_LANE, FloatArray, IntArray

# From one vehicle in a lane to the next, log travel time (or its kinematic error) changes by
# about this much.
SMOOTH_SPREAD = 0.03
# A chain's next pair lies at most BAND rows and columns on; each detection skipped between two
# pairs (a lane changer, about one in five in a queue) costs SKIP.
BAND = 4
SKIP = 1.5
# A chain may start afresh after any earlier pair at JUMP: no tie in travel time to the pair
# before (a gap of more than BAND vehicles, or a break in the flow).
JUMP = 6.0
# No vehicle passes at more than this multiple of the fastest speed either sensor measured.
TOP_SPEED_MARGIN = 2.0
# An anchored link's cost (-2 log density) is lowered by this much (odds of e^8): an anchor
# decides unless speeds and times speak clearly against it.
ANCHOR_BONUS = 16.0
# The share of a segment's anchors that the tracks built without them contradict, at and above
# which the anchors weigh in full (see `weigh_anchors`).
FULL_DISAGREEMENT = 0.2
# Upstream detections per block of a lane's chain (see `_blocks`).
BLOCK = 500


@dataclass
class Anchors:
    """Each detection's anchored predecessor (-1 = none), and what an anchored link into it
    saves in cost."""

    predecessor: IntArray
    bonus: FloatArray


def anchor_bonus(pairs: Pairs, anchors: Anchors | None) -> FloatArray:
    """What each candidate link's cost loses for being anchored (nothing if not). An anchor is
    evidence, not a command: where speeds and times tell vehicles apart, a wrong anchor still
    costs more than the true link; where they cannot (a queue), it decides."""
    if anchors is None:
        return np.zeros(pairs.a.size)
    return np.where(anchors.predecessor[pairs.b] == pairs.a, anchors.bonus[pairs.b], 0.0)


def weigh_anchors(s: Sensors, predecessor: IntArray, track: IntArray) -> Anchors:
    """Each segment's anchors weighed by how often the tracks built without them disagree: in
    free flow the two agree on nearly every link, and where they do not, it is as often the
    lane order that is wrong (a lane changer); in a queue they disagree on a third or more,
    and there the tracks are what is lost. The bonus grows with the share of disagreement, to
    ANCHOR_BONUS at FULL_DISAGREEMENT.

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
    bonus[anchored] = ANCHOR_BONUS * share[segment]
    return Anchors(predecessor, bonus)


def lane_order_anchors(s: Sensors, features: FeatureModel | None) -> IntArray:
    """Each detection's anchored predecessor at the sensor before (-1 = none); none where
    detectors do not report both lane and length."""
    anchor = np.full(s.time.size, -1, dtype=np.int64)
    f = s.features
    if f is None or features is None or not f.has_length():
        return anchor
    # The difference of two readings carries both their errors.
    length_spread = np.sqrt(2.0) * features.length_spread
    for k in range(s.positions.size - 1):
        up, down = s.members(k), s.members(k + 1)
        for lane in np.unique(f.lane[up]):
            if lane == NO_LANE:
                continue
            lane_up = up[(f.lane[up] == lane) & np.isfinite(f.log_length[up])]
            lane_down = down[(f.lane[down] == lane) & np.isfinite(f.log_length[down])]
            for a, b in _blocks(s, k, lane_up, lane_down):
                gain, log_travel, kinematic = _pair_terms(s, k, a, b, length_spread, features)
                for i, j in smooth_chain(gain, log_travel, kinematic):
                    anchor[b[j]] = a[i]
    return anchor


def _blocks(s: Sensors, k: int, up: IntArray, down: IntArray) -> list[tuple[IntArray, IntArray]]:
    """A lane's detections at sensors k and k + 1 (in time order) in blocks of at most BLOCK
    upstream detections, each with the downstream detections its vehicles can reach: the
    chain's work and memory grow with the block, never with the day. A chain breaks at a
    block's edge, so a few links there are left to the assignment."""
    gap = s.positions[k + 1] - s.positions[k]
    slowest = min(s.speed[up].min(initial=np.inf), s.speed[down].min(initial=np.inf))
    longest = TOP_SPEED_MARGIN * gap / slowest if np.isfinite(slowest) else 0.0
    blocks = []
    for first in range(0, up.size, BLOCK):
        a = up[first : first + BLOCK]
        reach = (s.time[down] > s.time[a[0]]) & (s.time[down] <= s.time[a[-1]] + longest)
        if reach.any():
            blocks.append((a, down[reach]))
    return blocks


def _pair_terms(
    s: Sensors, k: int, a: IntArray, b: IntArray, length_spread: float, features: FeatureModel
) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Every pair's gain (its length likelihood ratio; -inf where faster than any vehicle), log
    travel time and kinematic error (log travel time against the gap at the mean speed)."""
    gap = s.positions[k + 1] - s.positions[k]
    shortest = gap / (TOP_SPEED_MARGIN * max(s.top_speed[k], s.top_speed[k + 1]))
    travel = s.time[b][None, :] - s.time[a][:, None]
    possible = travel > shortest
    with np.errstate(divide="ignore", invalid="ignore"):
        log_travel = np.where(possible, np.log(travel), np.nan)
    speed = 0.5 * (s.speed[a][:, None] + s.speed[b][None, :])
    kinematic = log_travel - np.log(gap / speed)
    assert s.features is not None
    gain = _length_gain(s.features.log_length, a, b, length_spread, features, k + 1)
    return np.where(possible, gain, -np.inf), log_travel, kinematic


def _length_gain(
    log_length: FloatArray,
    a: IntArray,
    b: IntArray,
    spread: float,
    features: FeatureModel,
    sensor_b: int,
) -> FloatArray:
    """The log-likelihood ratio of every pair's two lengths: one vehicle read twice (a normal
    difference of `spread`), against b any vehicle that b's sensor sees (its length density)."""
    difference = log_length[b][None, :] - log_length[a][:, None]
    same = -0.5 * (difference / spread) ** 2 - np.log(spread * np.sqrt(2.0 * np.pi))
    density = length_density_at(features, sensor_b, log_length[b])
    gain: FloatArray = same - np.log(density)[None, :]
    return gain


def smooth_chain(
    gain: FloatArray, log_travel: FloatArray, kinematic: FloatArray
) -> list[tuple[int, int]]:
    """The order-keeping chain of pairs (i, j) of best score (rows and columns in time order):
    each pair's `gain` (-inf: impossible), minus, from one pair to the next, half the squared
    change of log travel time or of its kinematic error (the smaller), in units of
    SMOOTH_SPREAD, and SKIP per detection skipped between them; or a fresh start after any
    earlier pair at JUMP. Dynamic programming over the pairs, each looking back BAND rows and
    columns."""
    n, m = gain.shape
    score = np.full((n, m), -np.inf)
    back = np.full((n, m, 2), -1, dtype=np.int64)
    # best_before[i, j]: the best score over pairs in rows < i and columns < j, and where.
    best_before = np.full((n + 1, m + 1), -np.inf)
    where_before = np.full((n + 1, m + 1, 2), -1, dtype=np.int64)
    for i in range(n):
        row = np.zeros(m)  # a chain may start at any pair
        origin = np.full((m, 2), -1, dtype=np.int64)
        jump = best_before[i, :m] - JUMP
        better = jump > row
        row[better], origin[better] = jump[better], where_before[i, :m][better]
        # The BAND rows before, nearest first, all at once; one column shift at a time.
        before = slice(i - 1, max(i - BAND, 0) - 1 if i > BAND else None, -1)
        back_rows = np.arange(i - 1, max(i - BAND, 0) - 1, -1)
        skipped_rows = np.arange(back_rows.size)[:, None]  # rows skipped between the two pairs
        for dj in range(1, min(BAND, m - 1) + 1) if i else ():
            change = np.fmin(
                np.abs(log_travel[i, dj:] - log_travel[before, :-dj]),
                np.abs(kinematic[i, dj:] - kinematic[before, :-dj]),
            )
            step = score[before, :-dj] - 0.5 * (change / SMOOTH_SPREAD) ** 2
            step -= SKIP * (skipped_rows + dj - 1)
            step = np.where(np.isfinite(step), step, -np.inf)
            nearest = np.argmax(step, axis=0)
            best = step[nearest, np.arange(step.shape[1])]
            improved = np.flatnonzero(best > row[dj:])  # column j - dj of the pair before
            row[dj + improved] = best[improved]
            origin[dj + improved, 0] = back_rows[nearest[improved]]
            origin[dj + improved, 1] = improved
        score[i] = row + gain[i]
        back[i] = origin
        best_before[i + 1], where_before[i + 1] = _best_so_far(
            score[i], i, best_before[i], where_before[i]
        )
    if not np.isfinite(score).any() or score.max() <= 0.0:
        return []
    i, j = (int(x) for x in np.unravel_index(int(np.argmax(score)), score.shape))
    pairs = []
    while i >= 0 and j >= 0:
        pairs.append((i, j))
        i, j = (int(x) for x in back[i, j])
    return pairs[::-1]


def _best_so_far(
    row_score: FloatArray, i: int, before: FloatArray, where: IntArray
) -> tuple[FloatArray, IntArray]:
    """`before` and `where` (best over rows < i, columns < j) updated with row i."""
    m = row_score.size
    running = np.maximum.accumulate(row_score)
    argmax = np.maximum.accumulate(np.where(row_score >= running, np.arange(m), 0))
    # Over columns < j: shift by one.
    candidate = np.concatenate(([-np.inf], running))
    candidate_column = np.concatenate(([-1], argmax))
    take = candidate > before
    best = np.where(take, candidate, before)
    at = np.where(take[:, None], np.stack([np.full(m + 1, i), candidate_column], axis=1), where)
    return best, at
