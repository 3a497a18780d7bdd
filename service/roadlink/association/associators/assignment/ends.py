"""Where vehicles join or leave the road between two sensors: junctions' ramps.

The matching lets a detection stay unmatched at one fixed cost (`gate_cost` / 2, `matching.match`),
which says that a vehicle seen at one sensor and not at the next is rare, and so is one seen at a
sensor and not at the one before: a detector's miss, a false alarm, the batch's window
(`edges.py`). Past a junction it is not: an off-ramp takes a share of the vehicles between two
sensors, an on-ramp brings new ones. A vehicle that left before sensor k + 1 and one that joined
after it were linked to each other over k + 1 as if it had missed both (the cost of a link over
a missed sensor, `miss_cost`, is far less than leaving both apart), and the merging vehicles took
links from the vehicles they joined (SUMO, a three-lane motorway with two junctions: 8 points of
accuracy lost, against the same road without them).

So each sensor's share of detections whose track ends there (the road lost them before the
next sensor) and whose track starts there (they joined after the sensor before) is read off
the first tracks (`learn_road_ends`), beyond what the neighbouring sensor's starts (ends) say
the tracks merely broke there, and only where traffic flows at both sensors (a queue stores
vehicles between them). Where that excess stands out, every link out of (into) the sensor's
detections pays 2 log (1 + the excess share / the road's typical share of track ends): what
staying unmatched saves there (`edges.WindowEdges` adds it to the window's cost, capped as
that is). A link over a missed sensor pays what its ends pay. The forward pass, the re-pairing
sweep (`refine.fragment_ends`) and the copies (`tracks._births`) read it."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.params import FLOWING_SHARE
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]

# A sensor's excess counts only where it stands this many Poisson standard deviations above
# nothing, and is at least MIN_EXCESS detections.
SIGNIFICANCE = 3.0
MIN_EXCESS = 5
# The typical share is never taken below this (a road with no misses, false alarms or wrong
# links would have none, and any end would then stand out).
MIN_TYPICAL_SHARE = 0.01
# Traffic flows at a sensor where its SLOW_QUANTILE of speeds is at least `params.FLOWING_SHARE`
# of the road's fastest median speed.
SLOW_QUANTILE = 0.1
# Sensors with fewer counted detections than this say nothing of their share.
MIN_COUNTED = 20
# A detection is counted only where its window cost (`edges.WindowEdges`) is below this: its
# partner surely falls inside the window.
WINDOW_COUNTED = 0.05


@dataclass(frozen=True)
class RoadEnds:
    """Per sensor, what a link pays for leaving one of its detections (`leaving`: a link out of
    it, where vehicles leave the road before the next sensor) and for arriving at one
    (`arriving`: a link into it, where vehicles join after the sensor before)."""

    leaving: FloatArray
    arriving: FloatArray

    def any(self) -> bool:
        return bool(self.leaving.any() or self.arriving.any())


def learn_road_ends(
    s: Sensors,
    track: IntArray,
    window_leaving: FloatArray,
    window_arriving: FloatArray,
    copies: BoolArray | None = None,
) -> RoadEnds | None:
    """Each sensor's cost of a link out of and into it, from the `track`s (-1: unassigned, a
    track of its own); `window_*` are each detection's window costs (`edges.WindowEdges`). None
    where no sensor's share stands out. The `copies` (a passage's second report, left out of
    the tracks and later joined to its twin's target, `duplicates.join_duplicates`) are not
    counted: a second detector at a sensor's place, reporting every vehicle again 0.05 s later,
    read as every vehicle leaving and joining there (SUMO's free flow: 88.8 %, 98.3 % with the
    copies left out, 99.2 % without that detector).

    A link the tracks missed leaves a track's end at one sensor and a track's start at the next
    alike, so each sensor's ends count only beyond the starts at the next sensor (its starts,
    beyond the ends at the sensor before): where traffic stops at a signal or crawls in a queue
    the tracks break often, the two alike, and vehicles neither leave nor join there."""
    n_sensors = s.positions.size
    if n_sensors < 3:
        return None
    first, last = _track_ends(s, track)
    # Only detections between a sensor's first that came from upstream and its last that went
    # on downstream count: before and after them, a growing queue's or a crawl's vehicles have
    # their partners outside the batch, however the window's cost reads their travel times.
    inner = _between_linked(s, first, last)
    if copies is not None:
        inner &= ~copies
    n_leaving, ends = _counts(s, last, inner & (window_leaving < WINDOW_COUNTED))
    n_arriving, starts = _counts(s, first, inner & (window_arriving < WINDOW_COUNTED))
    # Ends at sensors 0 .. K-2 beyond the starts at 1 .. K-1, and the other way, where
    # traffic flows at both sensors.
    flows = _flowing(s)
    flows = flows[:-1] & flows[1:]
    leaving = np.where(flows, _excess_costs(n_leaving[:-1], ends[:-1], starts[1:]), 0.0)
    arriving = np.where(flows, _excess_costs(n_arriving[1:], starts[1:], ends[:-1]), 0.0)
    result = RoadEnds(np.append(leaving, 0.0), np.insert(arriving, 0, 0.0))
    return result if result.any() else None


def readable(s: Sensors) -> bool:
    """Whether any sensor's share could stand out (`learn_road_ends` finds none otherwise): two
    sensors or more, of three or more, with MIN_COUNTED detections. A paper-size batch has
    none, and skips the window's costs that the reading needs."""
    return s.positions.size >= 3 and int(np.count_nonzero(np.diff(s.start) >= MIN_COUNTED)) >= 2


def _between_linked(s: Sensors, first: BoolArray, last: BoolArray) -> BoolArray:
    """Whether each detection comes after its sensor's first detection that has a predecessor
    (from the start at the first sensor) and before its last that has a successor (to the end
    at the last sensor)."""
    n_sensors = s.positions.size
    sensor, time = s.sensor, s.time
    opens = np.full(n_sensors, np.inf)
    np.minimum.at(opens, sensor[~first], time[~first])
    closes = np.full(n_sensors, -np.inf)
    np.maximum.at(closes, sensor[~last], time[~last])
    opens[0], closes[-1] = -np.inf, np.inf
    inner: BoolArray = (time >= opens[sensor]) & (time <= closes[sensor])
    return inner


def _flowing(s: Sensors) -> BoolArray:
    """Whether traffic flows at each sensor: its slowest tenth of speeds at least FLOWING_SHARE of
    the road's fastest median. Where it does not, vehicles are stored between the sensors (a
    queue grows, a crawl outlasts the batch) and their counts need not match."""
    flowing: BoolArray = slow_speeds(s) >= FLOWING_SHARE * float(s.median_speed.max())
    return flowing


def slow_speeds(s: Sensors) -> FloatArray:
    """Each sensor's SLOW_QUANTILE of speeds, as np.quantile (linear) finds it, every sensor's at
    once from one sort by sensor and speed: sensor by sensor it was a tenth of a paper-size
    batch's association."""
    speeds = s.speed[s.order]
    ranked = speeds[np.lexsort((speeds, s.sensor[s.order]))]
    last = np.diff(s.start) - 1
    at = SLOW_QUANTILE * last
    below = np.floor(at).astype(np.int64)
    low = ranked[s.start[:-1] + below]
    high = ranked[s.start[:-1] + np.minimum(below + 1, last)]
    result: FloatArray = low + (high - low) * (at - below)
    return result


def _track_ends(s: Sensors, track: IntArray) -> tuple[BoolArray, BoolArray]:
    """Whether each detection is its track's first, and its last (an unassigned one is both)."""
    n = track.size
    first = np.ones(n, dtype=bool)
    last = np.ones(n, dtype=bool)
    assigned = np.flatnonzero(track >= 0)
    chain = s.by_track(assigned, track)
    same = track[chain[1:]] == track[chain[:-1]]
    last[chain[:-1][same]] = False
    first[chain[1:][same]] = False
    return first, last


def _counts(s: Sensors, flag: BoolArray, counted: BoolArray) -> tuple[IntArray, IntArray]:
    """Per sensor, its `counted` detections and how many of them are `flag`ged."""
    sensor = s.sensor[counted]
    size = s.positions.size
    return np.bincount(sensor, minlength=size), np.bincount(sensor[flag[counted]], minlength=size)


def _excess_costs(n: IntArray, k: IntArray, other: IntArray) -> FloatArray:
    """For each sensor, 2 log ((the road's typical share + its share of `k` beyond `other`) /
    the typical share) of its `n` counted detections, where that excess stands out (else 0).
    The typical share is the median of the sensors' shares of `k`: what misses, false alarms
    and wrong links leave."""
    usable = n >= MIN_COUNTED
    cost = np.zeros(n.size)
    if usable.sum() < 2:
        return cost
    typical = max(float(np.median(k[usable] / n[usable])), MIN_TYPICAL_SHARE)
    excess = k - other
    expected = typical * n
    # Each count is about Poisson: the excess's variance is their sum (and the typical's).
    noise = SIGNIFICANCE * np.sqrt(k + other + expected)
    stands_out = usable & (excess >= np.maximum(noise, MIN_EXCESS))
    cost[stands_out] = 2.0 * np.log1p(excess[stands_out] / expected[stands_out])
    return cost
