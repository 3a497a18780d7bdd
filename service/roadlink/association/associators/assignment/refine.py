"""Re-pairing with hindsight: track prefixes matched to track suffixes at every sensor boundary."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from roadlink.association.associators.assignment.anchors import Anchors, anchor_bonus
from roadlink.association.associators.assignment.arrays import same
from roadlink.association.associators.assignment.costs import Level, link_cost
from roadlink.association.associators.assignment.edges import WindowEdges
from roadlink.association.associators.assignment.gating import EverySensor, Gate, Pairs
from roadlink.association.associators.assignment.lane_inversions import (
    in_lane_order,
    keeps_lane_order,
)
from roadlink.association.associators.assignment.matching import (
    chosen_marginals,
    match,
    sure_matchings,
)
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.pace import incoming_pace, outgoing_pace
from roadlink.association.associators.assignment.params import (
    REFINE_GATE_FACTOR,
    AssignmentParams,
)
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.associators.assignment.tracks import (
    BoolArray,
    SweepSetup,
    level_terms,
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
    anchor: Anchors | None = None,
    tentative: bool = False,
    setup: SweepSetup | None = None,
) -> tuple[IntArray, bool]:
    """Re-pair the tracks across every sensor boundary, seeing both sides whole: the tracks,
    and whether any boundary changed a link.

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
    A `tentative` judging stops at the first boundary that changes a link. A sweep depends on
    the tracks' links alone, so one that changes none leaves the next sweep the same work, and
    its judging is the next sweep's. Links that lane order `anchor`s cost their bonus less, as
    in the forward pass. The gating and window edges come from `setup` where a forward pass
    worked them out with this model (`tracks.SweepSetup`).
    """
    nxt, prv = successors(s, track)
    in_track = track >= 0
    n_sensors = s.positions.size
    ready = None if setup is None else setup.of(model, REFINE_GATE_FACTOR * params.gate_cost)
    if ready is None:
        gate = Gate.of(s, model, params, REFINE_GATE_FACTOR * params.gate_cost)
        edges = WindowEdges.of(s, model, gate.gate / 2.0)
    else:
        gate, edges = ready
    lane_order = keeps_lane_order(s, params)
    if gate.every is not None:
        unchanged = Unchanged(s, model, params, gate.every, gate.gate, edges, anchor, lane_order)
        kept = unchanged.sweep(track, (nxt, prv), relink)
        if kept is not None:
            if confidence is not None:
                judge_links(confidence, kept, params.gate_cost)
            return _tracks_again(s, track, prv, in_track), False
    levels = [Summed.of(s, values, weights, nxt, in_track) for values, weights in level_terms(s)]
    changed = False
    judging = None if confidence is None else Judging(confidence, params.gate_cost)
    for k in range(1, n_sensors + 1):
        # Detections at sensor k - 1 got their final predecessor at the previous boundary.
        m = s.members(k - 1)
        m = m[prv[m] >= 0]
        for level in levels:
            level.extend_heads(m, prv[m])
        if k == n_sensors:
            break
        ends = ends_at_boundary(s, params, nxt, prv, in_track, k, gate)
        if ends is None:
            continue
        tails, pairs = ends
        cost = boundary_cost(params, model, pairs, levels, s, (nxt, prv))
        cost -= anchor_bonus(pairs, anchor)
        cost += edges.cost(pairs)
        cost += fragment_ends(s, params, anchor, model, k - 1, (nxt, prv), pairs)
        if relink:
            # Splitting a track costs more here than declining a link did: a track the forward
            # pass built is evidence in itself, so re-pairing must pay for itself.
            linked_a, linked_b = match(pairs.a, pairs.b, cost, gate.gate)
            if lane_order:
                linked = (linked_a, linked_b)
                apart = params.duplicate_window
                linked_a, linked_b = in_lane_order(s, nxt, k, linked, pairs, cost, apart)
            crossing = tails[nxt[tails] >= 0]
            was = nxt[tails]
            prv[nxt[crossing]] = -1
            nxt[crossing] = -1
            nxt[linked_a] = linked_b
            prv[linked_b] = linked_a
            changed = changed or not np.array_equal(nxt[tails], was)
        if judging is not None and not (tentative and changed):
            judging.add((pairs, cost, nxt[pairs.a] == pairs.b))
    if judging is not None:
        judging.finish()
    return tracks_from_links(s, prv, in_track), changed


# A boundary's candidate links, their costs, and which of them the tracks keep.
Judged = tuple[Pairs, FloatArray, BoolArray]


def _tracks_again(s: Sensors, track: IntArray, prv: IntArray, in_track: BoolArray) -> IntArray:
    """`tracks_from_links(s, prv, in_track)` of the links `track` holds (`successors`): the same
    tracks, which it numbers by their first detections in s.order's order. The forward pass
    numbers its births so, so where `track` already does, it is the answer (its detections out of
    a track at -1); else they are worked out sensor by sensor."""
    first = s.order[(in_track & (prv < 0))[s.order]]
    if same(track[first], np.arange(first.size)):
        return np.where(in_track, track, -1)
    return tracks_from_links(s, prv, in_track)


@dataclass(frozen=True)
class Unchanged:
    """A sweep worked out at once for every boundary, as if no boundary changed a link: on a
    paper-size batch (every sensor's links gated at once, `gating.EverySensor`) the first sweep
    usually changes none, and numpy's fixed costs of each boundary's ends and costs, some
    eighty calls, were most of its time.

    Were no link changed, every boundary would see the tracks' links as they are: its ends
    (`ends_at_boundary`), the prefixes' sums (final once the sweep has passed them) and the
    suffixes', and so its candidates and their costs, are those of the links as they are, and
    each number of a candidate is its own (the same numbers as boundary by boundary). Each
    boundary's matching then says whether it keeps its links; the first that does not ends
    this (None), and the sweep is made boundary by boundary."""

    s: Sensors
    model: SegmentModel
    params: AssignmentParams
    every: EverySensor
    gate: float
    edges: WindowEdges
    anchor: Anchors | None
    lane_order: bool  # whether the boundaries keep lane order (`lane_inversions`)

    def sweep(
        self, track: IntArray, links: tuple[IntArray, IntArray], relink: bool
    ) -> list[Judged] | None:
        """Each boundary's candidates, costs and kept links (`Judged`), in the sweep's order,
        if no boundary changes a link (`relink=False`: none does); else None. `links` are the
        `track`s' (`successors`)."""
        s, (nxt, _) = self.s, links
        n_sensors = s.positions.size
        in_track = track >= 0
        tails, crossing, heads = self.ends(links, in_track)
        pairs, boundary = self.candidates(links, in_track)
        levels = [Summed.along(s, v, w, track) for v, w in level_terms(s)]
        cost = boundary_cost(self.params, self.model, pairs, levels, s, links)
        if self.anchor is not None:  # else a bonus of 0, which changes no cost
            cost -= anchor_bonus(pairs, self.anchor)
        cost += self.edges.cost(pairs) + self.fragment_ends(boundary, links, pairs)
        cuts = np.searchsorted(boundary, np.arange(1, n_sensors + 1)).tolist()
        kept = nxt[pairs.a] == pairs.b
        # Boundaries whose matching surely keeps the links (by k, from 0), unsolved.
        sure = sure_matchings(pairs.a, pairs.b, cost, boundary, kept, self.gate, n_sensors)
        judged: list[Judged] = []
        for i in np.flatnonzero((tails > 0) & (heads > 0)).tolist():
            lo, hi = cuts[i], cuts[i + 1]
            here = pairs.part(lo, hi)
            if relink and not sure[i + 1]:
                # The boundary keeps its links if it links every tail that has a successor,
                # to that successor, and no other.
                linked_a, linked_b = match(here.a, here.b, cost[lo:hi], self.gate)
                if linked_a.size != crossing[i] or not same(nxt[linked_a], linked_b):
                    return None
            elif (
                relink and np.count_nonzero(kept[lo:hi] & (cost[lo:hi] < self.gate)) != crossing[i]
            ):
                return None  # a crossing link the matching cannot take (no candidate, or gated)
            if relink and self.reorders(i + 1, nxt, here, cost[lo:hi], kept[lo:hi]):
                return None
            judged.append((here, cost[lo:hi], kept[lo:hi]))
        return judged

    def reorders(
        self, k: int, nxt: IntArray, here: Pairs, cost: FloatArray, kept: BoolArray
    ) -> bool:
        """Whether lane order (`in_lane_order`) would exchange links that boundary k's
        matching keeps."""
        if not self.lane_order:
            return False
        a, b = here.a[kept], here.b[kept]
        apart = self.params.duplicate_window
        return not same(in_lane_order(self.s, nxt, k, (a, b), here, cost, apart)[1], b)

    def ends(
        self, links: tuple[IntArray, IntArray], in_track: BoolArray
    ) -> tuple[IntArray, IntArray, IntArray]:
        """For each boundary k (1 to n_sensors - 1): how many prefixes end before it (the
        tails of `ends_at_boundary`), how many of those have a successor, and how many suffixes
        start from it on (its heads)."""
        s, (nxt, prv) = self.s, links
        n_sensors, reach = s.positions.size, self.params.max_skip + 1
        x = np.flatnonzero(in_track)
        lag = np.arange(reach)
        # A detection at sensor p ends a prefix at boundaries p + 1 to p + reach, as long as
        # its successor lies at the boundary or beyond; starts a suffix at boundaries p - reach
        # + 1 to p, as long as its predecessor lies before the boundary.
        k = (s.sensor[x] + 1)[:, None] + lag
        successor = nxt[x][:, None]
        tail = (k < n_sensors) & ((successor < 0) | (s.sensor[np.maximum(successor, 0)] >= k))
        k_head = s.sensor[x][:, None] - lag
        predecessor = prv[x][:, None]
        head = (k_head >= 1) & ((predecessor < 0) | (s.sensor[np.maximum(predecessor, 0)] < k_head))
        crossing = tail & (successor >= 0)
        return (
            np.bincount(k[tail], minlength=n_sensors)[1:],
            np.bincount(k[crossing], minlength=n_sensors)[1:],
            np.bincount(k_head[head], minlength=n_sensors)[1:],
        )

    def candidates(
        self, links: tuple[IntArray, IntArray], in_track: BoolArray
    ) -> tuple[Pairs, IntArray]:
        """Every boundary's candidate links (`Gate.across` of its ends), boundary after
        boundary, and each one's boundary."""
        s, (nxt, prv) = self.s, links
        n_sensors, reach = s.positions.size, self.params.max_skip + 1
        k = np.arange(1, n_sensors)
        bounds = self.every.bounds
        lo = bounds[k]
        count = bounds[np.minimum(k + reach, n_sensors)] - lo
        at = np.repeat(lo - (np.cumsum(count) - count), count)
        at += np.arange(at.size)
        k = np.repeat(k, count)
        a, b = self.every.pairs.a[at], self.every.pairs.b[at]
        keep = in_track[a] & in_track[b] & (s.sensor[a] < k)
        keep &= (nxt[a] < 0) | (s.sensor[np.maximum(nxt[a], 0)] >= k)
        keep &= (prv[b] < 0) | (s.sensor[np.maximum(prv[b], 0)] < k)
        return self.every.pairs.take(at[keep]), k[keep]

    def fragment_ends(
        self, boundary: IntArray, links: tuple[IntArray, IntArray], pairs: Pairs
    ) -> FloatArray:
        """`fragment_ends` of every boundary's candidates (`boundary`: each one's)."""
        return fragment_ends(
            self.s, self.params, self.anchor, self.model, boundary - 1, links, pairs
        )


# Candidate links judged in one call, about: boundaries with fewer are judged together.
JUDGED_AT_ONCE = 4096


def judge_links(confidence: FloatArray, judged: list[Judged], gate: float) -> None:
    """Write into `confidence` how sure each kept link is against its rivals at each boundary
    (`matching.chosen_marginals`), a link judged at several boundaries (one over a missed
    detection) as at the last (`Judging`)."""
    judging = Judging(confidence, gate)
    for boundary in judged:
        judging.add(boundary)
    judging.finish()


@dataclass
class Judging:
    """`judge_links` boundary by boundary, as the sweep reaches them.

    Neighbouring boundaries with few links between them (a paper-size batch's every boundary)
    are judged in one call: numpy's fixed cost per call, over a dozen calls a boundary, was most
    of a small sweep's judging. Boundaries with many are judged alone, as one call over all of
    them would sort them all together. A boundary joins the call of those before it while the
    links so far stay within the same multiple of JUDGED_AT_ONCE; a call is made as soon as the
    next boundary starts another, so that a large batch holds one or two boundaries' links, not
    the whole road's (at 10^6 detections most of a sweep's memory)."""

    confidence: FloatArray
    gate: float
    pending: list[Judged] = field(default_factory=list)
    group: int = 0  # the links so far // JUDGED_AT_ONCE, of the pending boundaries
    links: int = 0  # the links of every boundary added so far

    def add(self, boundary: Judged) -> None:
        self.links += boundary[0].a.size
        group = self.links // JUDGED_AT_ONCE
        if self.pending and group != self.group:
            self.finish()
        self.pending.append(boundary)
        self.group = group

    def finish(self) -> None:
        """Judge the pending boundaries."""
        if self.pending:
            judge_together(self.confidence, self.pending, self.gate)
        self.pending = []


def judge_together(confidence: FloatArray, judged: list[Judged], gate: float) -> None:
    """`judge_links` of some boundaries in one call: each boundary's nodes are numbered apart
    (boundary times the number of detections, plus the detection), so no edge meets another
    boundary's, and every sum runs over one boundary's edges in the order it would alone."""
    n = confidence.size
    left = np.concatenate([pairs.a + i * n for i, (pairs, _, _) in enumerate(judged)])
    right = np.concatenate([pairs.b + i * n for i, (pairs, _, _) in enumerate(judged)])
    chosen = np.concatenate([kept for _, _, kept in judged])
    cost = np.concatenate([cost for _, cost, _ in judged])
    marginal = chosen_marginals(left, right, cost, chosen, gate)[chosen]
    b = right[chosen] % n
    # The last judgement of each link: its first in reverse.
    last = b.size - 1 - np.unique(b[::-1], return_index=True)[1]
    confidence[b[last]] = marginal[last]


def fragment_ends(
    s: Sensors,
    params: AssignmentParams,
    anchor: Anchors | None,
    model: SegmentModel,
    segment: int | IntArray,
    links: tuple[IntArray, IntArray],
    pairs: Pairs,
) -> FloatArray:
    """What joining fragments pays at the boundary after `segment` (each pair's, or all
    pairs'), where lane order's anchors weigh or vehicles leave or join the road.

    The sweep's gate is REFINE_GATE_FACTOR times the forward pass's, so that splitting a track
    must pay for itself; but it lets two fragments (a prefix without a suffix, a suffix without
    a prefix) join at a cost the pass refused. In a queue the anchors are what holds the tracks,
    and half the detections have no partner in the batch (`edges.py`): there the sweep shifted a
    lane's anchored chain by a vehicle to join such ends. Past a junction a vehicle that left the
    road and one that joined it are fragments by right (`ends.py`), and the sweep joined them
    over the sensor between. So each end that no link holds now pays the difference between the
    two gates' halves, in proportion to how much the segment's anchors weigh
    (`anchors.weigh_anchors`: in full in a queue, nothing in free flow), and in full where its
    sensor's vehicles leave (a prefix's end) or join (a suffix's start) the road."""
    weight: FloatArray | float = 0.0
    if anchor is not None and anchor.weight is not None:
        weight = anchor.weight[segment]
    ends = model.ends
    if ends is None and not np.any(weight):
        return np.zeros(pairs.a.size)
    nxt, prv = links
    weight_a = weight_b = np.broadcast_to(np.asarray(weight, dtype=np.float64), pairs.a.shape)
    if ends is not None:
        weight_a = np.maximum(weight_a, ends.leaving[s.sensor[pairs.a]] > 0)
        weight_b = np.maximum(weight_b, ends.arriving[s.sensor[pairs.b]] > 0)
    unheld = weight_a * (nxt[pairs.a] < 0) + weight_b * (prv[pairs.b] < 0)
    difference = (REFINE_GATE_FACTOR - 1.0) * params.gate_cost / 2.0
    result: FloatArray = difference * unheld
    return result


@dataclass
class Summed:
    """Sums of a value and of its weight over every detection's prefix (from its track's start to
    it) and suffix (from it to its track's end)."""

    value: FloatArray
    weight: FloatArray
    head_sum: FloatArray
    head_count: FloatArray
    tail_sum: FloatArray
    tail_count: FloatArray

    @classmethod
    def of(
        cls, s: Sensors, value: FloatArray, weight: FloatArray, nxt: IntArray, in_track: BoolArray
    ) -> Summed:
        # A suffix only involves links after its head, which the sweep has not reached yet, so
        # its sums stay valid; a prefix's are final once the sweep passes its last detection.
        weight = np.where(in_track, weight, 0.0)
        tail_sum, tail_count = suffix_sums(s, nxt, value * weight, weight)
        return cls(value, weight, value * weight, weight.copy(), tail_sum, tail_count)

    @classmethod
    def along(cls, s: Sensors, value: FloatArray, weight: FloatArray, track: IntArray) -> Summed:
        """`of`, with every head extended as a sweep that changes no link extends them (to the
        last sensor but one), the same numbers: a prefix's sum is its track's running sum, and
        a suffix's the running sum from its end, each one added as `extend_heads` and
        `suffix_sums` add it (IEEE addition commutes), for every track at once, row by row of
        one padded array (the tracks by their detections in road order)."""
        in_track = track >= 0
        weight = np.where(in_track, weight, 0.0)
        terms = np.stack([value * weight, weight])
        chain = s.by_track(in_track.nonzero()[0], track)
        ids = track[chain]
        new = np.ones(chain.size, dtype=bool)
        np.not_equal(ids[1:], ids[:-1], out=new[1:])
        row = new.cumsum() - 1
        start = new.nonzero()[0]
        column = np.arange(chain.size) - start[row]
        size = np.diff(np.append(start, chain.size))
        backwards = size[row] - 1 - column
        padded = np.zeros((2, 2, start.size, int(size.max(initial=0))))
        padded[0][:, row, column] = terms[:, chain]
        padded[1][:, row, backwards] = terms[:, chain]
        running = padded.cumsum(axis=3)
        head, tail = terms.copy(), terms.copy()
        extended = s.sensor[chain] < s.positions.size - 1
        head[:, chain[extended]] = running[0][:, row, column][:, extended]
        tail[:, chain] = running[1][:, row, backwards]
        return cls(value, weight, head[0], head[1], tail[0], tail[1])

    def extend_heads(self, m: IntArray, before: IntArray) -> None:
        """Detections m now follow `before` in their tracks."""
        self.head_sum[m] = self.value[m] * self.weight[m] + self.head_sum[before]
        self.head_count[m] = self.weight[m] + self.head_count[before]


def boundary_cost(
    params: AssignmentParams,
    model: SegmentModel,
    pairs: Pairs,
    levels: list[Summed],
    s: Sensors,
    links: tuple[IntArray, IntArray],
) -> FloatArray:
    """Cost of joining the prefix ending in each pair's a to the suffix starting with its b,
    given the prefix and suffix sums of each level term (`level_terms`) and the tracks' links
    (`nxt`, `prv`: the paces of the prefix's last link and the suffix's first)."""
    a, b = pairs.a, pairs.b
    nxt, prv = links
    speed = levels[0]
    before = Level(speed.head_sum[a] / speed.head_count[a], speed.head_count[a])
    after = Level(speed.tail_sum[b] / speed.tail_count[b], speed.tail_count[b])
    if model.pace is not None:
        before.pace = incoming_pace(model.pace, s, prv, a)
        after.pace = outgoing_pace(model.pace, s, nxt, b)
    if len(levels) > 1:
        length = levels[1]
        before.length_count = length.head_count[a]
        before.length_mean = length.head_sum[a] / np.maximum(before.length_count, 1.0)
        after.length_count = length.tail_count[b]
        after.length_mean = length.tail_sum[b] / np.maximum(after.length_count, 1.0)
    return link_cost(params, model, pairs, before, after, s)


def suffix_sums(
    s: Sensors, nxt: IntArray, total: FloatArray, count: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Sums of `total` and `count` from every detection to its track's end (accumulated
    backwards, sensor by sensor)."""
    total, count = total.copy(), count.copy()
    for k in range(s.positions.size - 1, -1, -1):
        m = s.members(k)
        m = m[nxt[m] >= 0]
        total[m] += total[nxt[m]]
        count[m] += count[nxt[m]]
    return total, count


def ends_at_boundary(
    s: Sensors,
    params: AssignmentParams,
    nxt: IntArray,
    prv: IntArray,
    in_track: BoolArray,
    k: int,
    gate: Gate,
) -> tuple[IntArray, Pairs] | None:
    """The prefixes' last detections before sensor k and the candidate links from them to the
    suffixes' first detections from sensor k on, those within the `gate` on the travel time
    alone (None when either side has none)."""
    reach = params.max_skip + 1
    n_sensors = s.positions.size
    # The detections of the sensors before k, and of those from k on: runs of s.order.
    before = s.order[s.start[max(0, k - reach)] : s.start[k]]
    tails = before[
        in_track[before] & ((nxt[before] < 0) | (s.sensor[np.maximum(nxt[before], 0)] >= k))
    ]
    after = s.order[s.start[k] : s.start[min(n_sensors, k + reach)]]
    heads = after[in_track[after] & ((prv[after] < 0) | (s.sensor[np.maximum(prv[after], 0)] < k))]
    if tails.size == 0 or heads.size == 0:
        return None
    is_head = np.zeros(s.time.size, dtype=bool)
    is_head[heads] = True
    return tails, gate.across(k, tails, is_head)
