"""Re-pairing with hindsight: track prefixes matched to track suffixes at every sensor boundary."""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.costs import Level, link_cost
from roadlink.association.associators.assignment.gating import Pairs, gated_pairs
from roadlink.association.associators.assignment.matching import chosen_marginals, match
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import (
    REFINE_GATE_FACTOR,
    AssignmentParams,
)
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.associators.assignment.tracks import (
    BoolArray,
    successors,
    tracks_from_links,
)
from roadlink.association.detections import FloatArray, IntArray


def refine_boundaries(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    track: IntArray,
    confidence: FloatArray | None = None,
    relink: bool = True,
) -> IntArray:
    """Re-pair the tracks across every sensor boundary, seeing both sides whole.

    The sequential pass chooses each link knowing only the past. Here, boundary after boundary,
    every track is cut before sensor k into a prefix and a suffix, and prefixes are matched to
    suffixes again with the same link cost, its speed-level term now comparing the prefix's mean
    speed with the suffix's. This undoes swaps between targets that crossed at near-equal speeds
    and joins fragments a failed link split (a prefix without a suffix meets a suffix without a
    prefix). Each boundary costs time in proportion to the detections near it.

    With `confidence` (one value per detection), the sweep also writes there, for each link it
    keeps, how sure it is against its rivals at the boundary (`matching.chosen_marginals`, every
    piece free to stay alone at half of `gate_cost`): a link is decided, and judged, for the
    last time at the boundary before its far end. `relink=False` judges the links as they are.
    """
    nxt, prv = successors(s, track)
    in_track = track >= 0
    n_sensors = s.positions.size
    u = s.relative_speed
    # A suffix only involves links after its head, which this sweep has not reached yet, so its
    # sums stay valid.
    tail_sum, tail_count = suffix_sums(s, nxt, in_track)
    # Prefix sums (from the track's start to a detection), final once the sweep passes it.
    head_sum = np.where(in_track, u, 0.0)
    head_count = in_track.astype(np.float64)
    gate = REFINE_GATE_FACTOR * params.gate_cost
    for k in range(1, n_sensors + 1):
        # Detections at sensor k - 1 got their final predecessor at the previous boundary.
        m = s.members(k - 1)
        m = m[prv[m] >= 0]
        head_sum[m] = u[m] + head_sum[prv[m]]
        head_count[m] = 1.0 + head_count[prv[m]]
        if k == n_sensors:
            break
        ends = ends_at_boundary(s, model, params, nxt, prv, in_track, k, gate)
        if ends is None:
            continue
        tails, pairs = ends
        cost = boundary_cost(params, model, pairs, (head_sum, head_count), (tail_sum, tail_count))
        if relink:
            # Splitting a track costs more here than declining a link did: a track the forward
            # pass built is evidence in itself, so re-pairing must pay for itself.
            linked_a, linked_b = match(pairs.a, pairs.b, cost, gate)
            crossing = tails[nxt[tails] >= 0]
            prv[nxt[crossing]] = -1
            nxt[crossing] = -1
            nxt[linked_a] = linked_b
            prv[linked_b] = linked_a
        if confidence is not None:
            chosen = nxt[pairs.a] == pairs.b
            marginal = chosen_marginals(pairs.a, pairs.b, cost, chosen, params.gate_cost)
            confidence[pairs.b[chosen]] = marginal[chosen]
    return tracks_from_links(s, prv, in_track)


def boundary_cost(
    params: AssignmentParams,
    model: SegmentModel,
    pairs: Pairs,
    heads: tuple[FloatArray, FloatArray],
    tails: tuple[FloatArray, FloatArray],
) -> FloatArray:
    """Cost of joining the prefix ending in each pair's a to the suffix starting with its b,
    given per detection the sum and count of relative speeds of the prefix up to it (`heads`)
    and of the suffix from it (`tails`)."""
    a, b = pairs.a, pairs.b
    (head_sum, head_count), (tail_sum, tail_count) = heads, tails
    return link_cost(
        params,
        model,
        pairs,
        Level(head_sum[a] / head_count[a], head_count[a]),
        Level(tail_sum[b] / tail_count[b], tail_count[b]),
    )


def suffix_sums(s: Sensors, nxt: IntArray, in_track: BoolArray) -> tuple[FloatArray, FloatArray]:
    """Sum of relative speeds, and count, from every detection to its track's end (accumulated
    backwards, sensor by sensor)."""
    total = np.where(in_track, s.relative_speed, 0.0)
    count = in_track.astype(np.float64)
    for k in range(s.positions.size - 1, -1, -1):
        m = s.members(k)
        m = m[nxt[m] >= 0]
        total[m] += total[nxt[m]]
        count[m] += count[nxt[m]]
    return total, count


def ends_at_boundary(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    nxt: IntArray,
    prv: IntArray,
    in_track: BoolArray,
    k: int,
    gate: float,
) -> tuple[IntArray, Pairs] | None:
    """The prefixes' last detections before sensor k and the candidate links from them to the
    suffixes' first detections from sensor k on, those costing less than `gate` on the travel
    time alone (None when either side has none)."""
    reach = params.max_skip + 1
    n_sensors = s.positions.size
    before = np.concatenate([s.members(q) for q in range(max(0, k - reach), k)])
    tails = before[
        in_track[before] & ((nxt[before] < 0) | (s.sensor[np.maximum(nxt[before], 0)] >= k))
    ]
    after = np.concatenate([s.members(q) for q in range(k, min(n_sensors, k + reach))])
    heads = after[in_track[after] & ((prv[after] < 0) | (s.sensor[np.maximum(prv[after], 0)] < k))]
    if tails.size == 0 or heads.size == 0:
        return None
    is_head = np.zeros(s.time.size, dtype=bool)
    is_head[heads] = True
    found: list[Pairs] = []
    for q in range(k, min(k + reach, n_sensors)):
        near = tails[s.sensor[tails] >= q - reach]
        pairs = gated_pairs(s, model, params, near, q, gate)
        found.append(pairs.take(is_head[pairs.b]))
    return tails, Pairs.concatenate(found)
