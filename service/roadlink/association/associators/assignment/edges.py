"""The batch's time window: a detection near its edge may have no partner inside it.

A batch holds what every sensor saw over some window of time. A vehicle seen upstream shortly
before the window closes reaches the next sensor after it; one seen downstream shortly after the
window opens passed the sensor before it earlier. Where travel times are short against the
window (free flow: seconds against minutes) this touches a few detections at each end; in a
crawl (a few minutes a segment, in a window of five) it touches half of them. The matching lets
every detection stay unmatched at a fixed cost (`gate_cost` / 2, `matching.match`), which says
that a detection without a partner is rare: at the edge it is not, and such detections were
linked to any partner within the gate, vehicles from before the window to vehicles from after
it, at travel times a third or more shorter than the true ones.

So a link pays for what the window says of its ends (`WindowEdges`): -2 log of the chance that
a's successor at the next sensor falls inside the window, and the same of b's predecessor at the
sensor before, each from the travel time that the segment's model predicts at a's (b's) speed and
the other sensor's median speed, as a log-normal of spread at least EDGE_SPREAD. A detection far
from the edges pays nothing; one whose partner surely lies outside pays up to the whole of what
staying unmatched costs, so it is linked only where the link is as likely as one between two
detections that surely have partners. The chance is a detection's own, read at the neighbouring
sensor: a link over a missed sensor pays what its ends would pay to their neighbours.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.sensors import (
    Sensors,
    arrival_keys_of,
    travel_time,
)
from roadlink.association.detections import FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]

# The spread (log travel time) of the prediction from one end alone: the far end's speed is
# unknown, taken as its sensor's median, and a queue's spot speeds tell its crawl poorly.
EDGE_SPREAD = 0.3
# Beyond this many spreads inside the window, the chance of falling outside costs under 1e-4:
# none is computed.
EDGE_FAR = 4.0


@dataclass(frozen=True)
class WindowEdges:
    """What each detection costs a link for the window: as the link's upstream end (`leaving`:
    its successor may come after the window closes) and as its downstream end (`arriving`: its
    predecessor may have passed before the window opened)."""

    leaving: FloatArray
    arriving: FloatArray

    @classmethod
    def of(cls, s: Sensors, model: SegmentModel, unmatched: float) -> WindowEdges:
        """Each detection's two costs, at most `unmatched` (what staying unmatched costs).

        Only the detections near an edge are worked out: one whose room to the edge exceeds
        what its segment's slowest detection would take, EDGE_FAR spreads late, pays nothing
        (on a long batch, all but the first and last minutes)."""
        return cls.each(s, model, (unmatched,))[0]

    @classmethod
    def each(
        cls, s: Sensors, model: SegmentModel, unmatched: tuple[float, ...]
    ) -> list[WindowEdges]:
        """`of` at each of these `unmatched` costs, worked out once: only the cap differs (a
        forward pass and the re-pairing sweep after it, with the same model)."""
        n = s.time.size
        if s.positions.size < 2:
            return [cls(np.zeros(n), np.zeros(n)) for _ in unmatched]
        segment = _Segments.of(s, model)
        n_segments = s.positions.size - 1
        # The batch's window, every sensor's: one that stopped reporting part-way through (or
        # started late) missed the vehicles after (before) that, which links over it bridge.
        opens, closes = float(s.first_time.min()), float(s.last_time.max())
        closing = np.full(n_segments, closes)
        up = _near(s, range(n_segments), closing, segment.leaving_reach(s), before=False)
        p = s.sensor[up]
        ahead = segment.bias[p] + np.log(
            travel_time(segment.gap[p], s.speed[up], s.median_speed[p + 1], segment.skew[p])
        )
        room = closes - s.time[up]
        up_outside = _Outside.of(room, ahead, segment.spread[p])
        opening = np.full(n_segments, opens)
        down = _near(s, range(1, n_segments + 1), opening, segment.arriving_reach(s), before=True)
        p = s.sensor[down] - 1
        behind = segment.bias[p] + np.log(
            travel_time(segment.gap[p], s.median_speed[p], s.speed[down], segment.skew[p])
        )
        room = s.time[down] - opens
        down_outside = _Outside.of(room, behind, segment.spread[p])
        edges = []
        ends = model.ends
        for cap in unmatched:
            leaving, arriving = np.zeros(n), np.zeros(n)
            leaving[up] = up_outside.cost(cap)
            arriving[down] = down_outside.cost(cap)
            if ends is not None:
                # Where vehicles leave or join the road (`ends.py`): capped as the window is.
                np.minimum(leaving + ends.leaving[s.sensor], cap, out=leaving)
                np.minimum(arriving + ends.arriving[s.sensor], cap, out=arriving)
            edges.append(cls(leaving, arriving))
        return edges

    def cost(self, pairs: Pairs) -> FloatArray:
        """What each candidate link a -> b pays for the window."""
        result: FloatArray = self.leaving[pairs.a] + self.arriving[pairs.b]
        return result


@dataclass(frozen=True)
class _Segments:
    """Each segment's (by the sensor it starts at) gap, travel-time bias and skew, and the spread
    a travel time predicted from one end has."""

    gap: FloatArray
    bias: FloatArray
    skew: FloatArray
    spread: FloatArray

    @classmethod
    def of(cls, s: Sensors, model: SegmentModel) -> _Segments:
        return cls(
            np.diff(s.positions),
            model.log_bias[:-1, 1],
            model.skew[:-1, 1],
            np.maximum(model.time_spread[:-1, 1], EDGE_SPREAD),
        )

    def leaving_reach(self, s: Sensors) -> FloatArray:
        """For every segment, the longest room to the window's close that can cost a detection at
        its upstream sensor anything: what the slowest detection there would take, EDGE_FAR
        spreads late."""
        return self._late(
            travel_time(self.gap, s.slowest_speed[:-1], s.median_speed[1:], self.skew)
        )

    def arriving_reach(self, s: Sensors) -> FloatArray:
        """The same from the window's opening, for a detection at the downstream sensor."""
        return self._late(
            travel_time(self.gap, s.median_speed[:-1], s.slowest_speed[1:], self.skew)
        )

    def _late(self, travel: FloatArray) -> FloatArray:
        result: FloatArray = np.exp(self.bias + EDGE_FAR * self.spread) * travel
        return result


def _near(
    s: Sensors, sensors: range, edge: FloatArray, reach: FloatArray, *, before: bool
) -> IntArray:
    """The detections of each of these sensors within its `reach` of its `edge` (`edge[k]` and
    `reach[k]` for the k-th sensor named): after edge - reach where the edge closes the window,
    before edge + reach where it opens it. Each sensor's detections are sorted by time, so this
    is one search a sensor, whatever the batch's length; every sensor's at once, among the
    arrivals as (sensor, time) (`Sensors.arrival_keys`), where no time is NaN."""
    at_once = _near_at_once(s, sensors, edge + reach if before else edge - reach, before)
    if at_once is not None:
        return at_once
    parts = []
    for k, q in enumerate(sensors):
        lo, hi = int(s.start[q]), int(s.start[q + 1])
        times = s.sorted_time[lo:hi]
        if before:
            hi = lo + int(np.searchsorted(times, edge[k] + reach[k], side="left"))
        else:
            lo += int(np.searchsorted(times, edge[k] - reach[k], side="right"))
        parts.append(s.order[lo:hi])
    return np.concatenate(parts) if parts else np.zeros(0, dtype=np.int64)


def _near_at_once(s: Sensors, sensors: range, bound: FloatArray, before: bool) -> IntArray | None:
    """`_near` of every sensor at once, given each sensor's bound (edge + reach before the
    opening edge, edge - reach after the closing one): one binary search each among the
    arrivals as (sensor, time); None where a time or a bound is NaN."""
    keys = s.arrival_keys
    if keys is None or np.isnan(bound).any():
        return None
    q = np.arange(sensors.start, sensors.stop)
    ends = arrival_keys_of(q, bound)
    if before:
        lo, hi = s.start[q], keys.searchsorted(ends, side="left")
    else:
        lo, hi = keys.searchsorted(ends, side="right"), s.start[q + 1]
    count = hi - lo
    at = (lo - (count.cumsum() - count)).repeat(count)
    at += np.arange(at.size)
    near: IntArray = s.order[at]
    return near


@dataclass(frozen=True)
class _Outside:
    """-2 log P(travel time <= room) for a log-normal travel time of centre `log_expected` and
    `spread`, where the room is less than EDGE_FAR spreads beyond the centre (`near`); 0 beyond.
    No room at all is -2 log 0 = inf, capped by `cost`."""

    near: BoolArray
    minus_two_log: FloatArray  # of the detections `near`

    @classmethod
    def of(cls, room: FloatArray, log_expected: FloatArray, spread: FloatArray) -> _Outside:
        from scipy.special import log_ndtr  # on first use, as in `matching.match`

        with np.errstate(divide="ignore"):
            z = (np.log(np.maximum(room, 0.0)) - log_expected) / spread
        near = z < EDGE_FAR
        return cls(near, -2.0 * log_ndtr(z[near]))

    def cost(self, unmatched: float) -> FloatArray:
        """The costs, at most `unmatched`."""
        cost = np.zeros(self.near.size)
        cost[self.near] = np.minimum(self.minus_two_log, unmatched)
        return cost
