"""Lane order at a boundary: two vehicles that keep to the same lanes do not pass each other.

A boundary's re-pairing (`refine`) is a linear assignment: each link is costed alone, and
nothing in it says that two links cross. In a queue the costs hardly tell a vehicle from the
one ahead or behind, and the matching crosses links that the road does not: on SUMO's
stop-and-go (lane, length and class reported, the committed seed-0 case) `assignment`'s links
crossed 10 times where the true links never do. Two vehicles in one lane at sensor k - 1 that
are in one lane at sensor k again pass each other only by leaving that lane and coming back: of
such successive pairs (successive in the upstream lane, bound for the same lane) in SUMO's
traffic, none to 0.3 % cross in free flow, dense traffic, stop-and-go, slow zones, lane drops,
on irregular spacing and at junctions; 0.5-1 % with faulty detectors and in congestion; 4-12 %
in queues where three lanes squeeze into one and vehicles weave.

So after the matching, two successive links between the same lanes that cross are exchanged
(a -> y, b -> x for a -> x, b -> y) where that costs less than the odds against their crossing:
2 log((1 - r) / r), r the share of such successive pairs that cross among the links the tracks
held over that segment before (a prior of `PRIOR_CROSSING`, weighed as `PRIOR_PAIRS` pairs).
Where the road keeps its lanes the tracks' few crossings make crossing dear; where vehicles
weave, r is high and the costs decide. Exchanging two successive links uncrosses them and leaves
every other pair's order as it was, so each exchange takes one crossing away at less than its
price, and the exchanges end. Two reports of one lane less than the duplicate window apart are
one passage reported twice or a false alarm beside a vehicle (no two vehicles follow that
closely), so their order says nothing and they are never exchanged.
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import NO_LANE, FloatArray, IntArray

# Before the segment's tracks say otherwise: one pair in twenty crosses, worth twenty pairs.
PRIOR_CROSSING = 0.05
PRIOR_PAIRS = 20.0
# Exchanges are made in rounds (each link in one exchange a round), until none pays.
MAX_ROUNDS = 20


def keeps_lane_order(s: Sensors, params: AssignmentParams) -> bool:
    """Whether crossing links are exchanged: where detectors report lanes and lane order is
    wanted (`lane_anchors`, and the features weigh: `feature_weight` > 0)."""
    return (
        s.features is not None
        and s.features.has_lane()
        and params.lane_anchors
        and params.feature_weight > 0
    )


def in_lane_order(
    s: Sensors,
    nxt: IntArray,
    k: int,
    linked: tuple[IntArray, IntArray],
    pairs: Pairs,
    cost: FloatArray,
    apart: float,
) -> tuple[IntArray, IntArray]:
    """Boundary k's matching `linked` (a -> b, costed by `cost` over `pairs`) with its crossing
    links between the same lanes exchanged where the segment's links as the tracks held them
    (`nxt`, from sensor k - 1 to k) say crossing is rarer than the exchange costs; reports less
    than `apart` apart in time are never exchanged."""
    held = s.members(k - 1)
    held = held[nxt[held] >= 0]
    held = held[s.sensor[nxt[held]] == k]
    return uncross(s, linked, pairs, cost, crossing_cost(s, held, nxt[held], apart), apart)


def crossing_cost(s: Sensors, a: IntArray, b: IntArray, apart: float) -> float:
    """2 log((1 - r) / r): what the links a -> b (sensor k - 1 to k) say crossing costs, r the
    share of successive links between the same lanes that cross (see the module's docstring)."""
    order, group = _by_lanes(s, a, b)
    time_a, time_b = s.time[a[order]], s.time[b[order]]
    successive = (group[1:] == group[:-1]) & (np.diff(time_a) > apart)
    crossed = successive & (time_b[:-1] - time_b[1:] > apart)
    rate = (crossed.sum() + PRIOR_CROSSING * PRIOR_PAIRS) / (successive.sum() + PRIOR_PAIRS)
    return 2.0 * float(np.log((1.0 - rate) / rate))


def uncross(
    s: Sensors,
    linked: tuple[IntArray, IntArray],
    pairs: Pairs,
    cost: FloatArray,
    penalty: float,
    apart: float,
) -> tuple[IntArray, IntArray]:
    """The matching `linked` (a boundary's links a -> b, costed by `cost` over `pairs`) with its
    crossing links between the same lanes exchanged where that costs less than `penalty`;
    reports less than `apart` apart in time are never exchanged."""
    a, b = linked[0], linked[1].copy()
    costed = _Costed(pairs, cost, s.time.size)
    for _ in range(MAX_ROUNDS):
        first, second, saving = _crossings(s, a, b, costed, apart)
        worth = saving > -penalty
        if not worth.any():
            break
        taken = np.zeros(a.size, dtype=bool)
        best_first = np.argsort(-saving[worth], kind="stable")
        for i, j in zip(first[worth][best_first], second[worth][best_first], strict=True):
            if not (taken[i] or taken[j]):
                taken[i] = taken[j] = True
                b[i], b[j] = b[j], b[i]
    return a, b


class _Costed:
    """The cost of any pair of `pairs`, looked up by its ends (NaN for a pair not there)."""

    def __init__(self, pairs: Pairs, cost: FloatArray, n: int) -> None:
        self._n = n
        keys = pairs.a * n + pairs.b
        order = np.argsort(keys)
        self._keys = keys[order]
        self._cost = cost[order]

    def __call__(self, a: IntArray, b: IntArray) -> FloatArray:
        keys = a * self._n + b
        if self._keys.size == 0:
            return np.full(keys.size, np.nan)
        at = np.minimum(np.searchsorted(self._keys, keys), self._keys.size - 1)
        return np.where(self._keys[at] == keys, self._cost[at], np.nan)


def _crossings(
    s: Sensors, a: IntArray, b: IntArray, costed: _Costed, apart: float
) -> tuple[IntArray, IntArray, FloatArray]:
    """Every two successive links between the same lanes that cross, as places in (a, b), and
    what exchanging their far ends saves (negative: it costs). Exchanging two successive links
    uncrosses them and leaves every other pair's order as it was, so each exchange made takes
    one crossing away: the rounds end."""
    one_step = np.flatnonzero(s.sensor[b] == s.sensor[a] + 1)
    order, group = _by_lanes(s, a[one_step], b[one_step])
    places = one_step[order]
    time_a, time_b = s.time[a[places]], s.time[b[places]]
    cross = (
        (group[1:] == group[:-1]) & (np.diff(time_a) > apart) & (time_b[:-1] - time_b[1:] > apart)
    )
    at = np.flatnonzero(cross)
    i, j = places[at], places[at + 1]
    saving = costed(a[i], b[i]) + costed(a[j], b[j]) - costed(a[i], b[j]) - costed(a[j], b[i])
    known = ~np.isnan(saving)
    return i[known], j[known], saving[known]


def _by_lanes(s: Sensors, a: IntArray, b: IntArray) -> tuple[IntArray, IntArray]:
    """The links a -> b whose ends report lanes, ordered by (lane at a, lane at b, a's time):
    their places in (a, b) and their lane pairs' keys."""
    assert s.features is not None
    lane = s.features.lane
    reported = np.flatnonzero((lane[a] != NO_LANE) & (lane[b] != NO_LANE))
    group = lane[a[reported]] * s.features.n_lanes + lane[b[reported]]
    by = np.lexsort((s.time[a[reported]], group))
    return reported[by], group[by]
