"""Two naive groupings that an associator must beat, as references in the accuracy benchmarks.

- `fifo`: the k-th detection at every sensor is the k-th vehicle (pure first in, first out).
- `chain`: each pair of neighbouring sensors matched by one linear assignment on a fixed
  kinematic cost (the travel time the two speeds predict against the one observed), the links
  chained into tracks. Nothing is learned and nothing is looked at beyond the two sensors.

Neither is an associator a user should pick; they show what order alone, and what speeds alone,
carry in a kind of traffic.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable

import numpy as np
import numpy.typing as npt
from scipy.optimize import linear_sum_assignment

from roadlink.association.detections import Detections, IntArray

# A link whose travel time is off the kinematic prediction by more than this factor (either way)
# is not made: those detections start or end a track instead.
CHAIN_GATE = np.log(2.0)


def fifo_groups(detections: Detections) -> IntArray:
    """Group k holds the k-th detection (in time) of every sensor."""
    groups = np.empty(len(detections), dtype=np.int64)
    for position in np.unique(detections.position):
        at = np.flatnonzero(detections.position == position)
        groups[at[np.argsort(detections.timestamp[at], kind="stable")]] = np.arange(at.size)
    return groups


def chain_groups(detections: Detections) -> IntArray:
    """Links between neighbouring sensors by one assignment each, chained into tracks."""
    positions = np.unique(detections.position)
    successor = np.full(len(detections), -1, dtype=np.int64)
    for upstream, downstream in itertools.pairwise(positions):
        a = np.flatnonzero(detections.position == upstream)
        b = np.flatnonzero(detections.position == downstream)
        rows, cols = _links(detections, a, b, downstream - upstream)
        successor[a[rows]] = b[cols]
    return chained_groups(successor)


def chained_groups(successor: IntArray) -> IntArray:
    """Groups from links: each detection's successor in its track (-1 = none)."""
    groups = np.full(successor.size, -1, dtype=np.int64)
    has_predecessor = np.zeros(successor.size, dtype=bool)
    has_predecessor[successor[successor >= 0]] = True
    for group, start in enumerate(np.flatnonzero(~has_predecessor)):
        node = start
        while node >= 0:
            groups[node] = group
            node = successor[node]
    return groups


def _links(
    detections: Detections, a: IntArray, b: IntArray, gap: float
) -> tuple[IntArray, IntArray]:
    travel = detections.timestamp[b][None, :] - detections.timestamp[a][:, None]
    speed = 0.5 * (detections.velocity[a][:, None] + detections.velocity[b][None, :])
    with np.errstate(divide="ignore", invalid="ignore"):
        cost = np.abs(np.log(travel * speed / gap))
    cost = np.where((travel > 0) & np.isfinite(cost), cost, np.inf)
    return gated_assignment(cost, alone=CHAIN_GATE, gate=CHAIN_GATE)


def gated_assignment(
    cost: npt.NDArray[np.float64], alone: float, gate: float
) -> tuple[IntArray, IntArray]:
    """One-to-one links of least total cost, each row and column free to stay unmatched at cost
    `alone` (a square problem with dummy rows and columns); links of cost `gate` or more are
    dropped."""
    n, m = cost.shape
    padded = np.full((n + m, m + n), alone)
    padded[:n, :m] = np.minimum(cost, 10 * gate)
    padded[n:, m:] = 0.0
    rows, cols = linear_sum_assignment(padded)
    real = (rows < n) & (cols < m)
    rows, cols = rows[real], cols[real]
    kept = cost[rows, cols] < gate
    return rows[kept], cols[kept]


REFERENCES: dict[str, Callable[[Detections], IntArray]] = {
    "fifo": fifo_groups,
    "chain": chain_groups,
}
