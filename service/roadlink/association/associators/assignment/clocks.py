"""Sensors' clocks: a sensor whose clock runs seconds ahead or behind the others, found and set
right before anything is linked.

A field detector stamps each passage with its own clock, and clocks that no time server keeps in
step drift by seconds or more. A sensor whose clock runs δ late adds δ to every travel time into
it and takes δ from every travel time out of it. The segments' travel-time biases are factors
(`SegmentModel.log_bias`), which cannot say that: past a few seconds the travel times out of
such a sensor are shorter than any vehicle could drive, or below zero, and the tracks break
there (SUMO's dense motorway with lane and length, travel times of 9 s: 99.8 % of the detections
right on time, 74 % with one middle sensor 20 s late).

So each segment's lag is measured first: the travel times of its pairs of detections less what
the kinematic prediction says (`sensors.travel_time`), whose histogram peaks where the true
pairs are, above the background of unrelated pairs (`Road.lags`). A clock shifts the lags on
both sides of its sensor by the same seconds, opposite ways; a slow zone, a queue or a speed
that a sensor reads wrongly move one side, or both the same way, or spread the lags so that no
peak stands out. A sensor is set right (`clock_offsets`) where both of its segments' lags peak
clearly and mirror each other. An offset of 30 % of a travel time or more is set right on
that alone. A smaller one, down to two of the histogram's bins (a second at least), only where
matching confirms it (`Road.confirms`): in dense traffic a lag's highest bin may sit a headway
off, on the comb of neighbouring vehicles, and two such bins may mirror by chance (the committed
dense case, on time, has them 1.3 s off either side of one sensor; set "right", it lost 10
points). Matching the sampled detections to their neighbours' by time and speed tells them
apart: under a false offset each vehicle pairs with its neighbour, whose speed differs. The
smaller offsets were missed before (a middle sensor of dense traffic 1.5 s early or late: 77
and 81 % over five seeds against 92 % on time; now 92 %), and offsets under two bins stay the
learned biases' (`weak_bias.clock_shifts`).

The first and the last sensor have one neighbour each, and nothing to mirror: an offset of
their clocks looks like traffic that takes longer (or shorter) over their one segment. But a
clock adds the same seconds to every travel time, where traffic that takes longer does so in
proportion (the learned biases are factors), so an end sensor is set right where its segment's
lag fits as a clock's (`Road.fits_as_clock`): matching its pairs costs clearly less with every
travel time longer by the lag than with them on time or longer by one factor. That tells the
two apart where speeds differ from vehicle to vehicle (a factor of 3.4 on free flow's 7-12 s
travel times is no 20 s offset); where every vehicle keeps one speed they are alike, and the
learned bias takes the offset as well. The neighbour's other segment must be on time, or the
lag may be the neighbour's own clock. Before, an end sensor's clock 20 s late cost SUMO's
dense motorway 7-8 points, free flow 9. Every sensor's clock stays as it is where the road has
fewer than three.

A sensor installed some metres from the position the batch gives it shifts the travel times
either side of it by those metres over each vehicle's speed, opposite ways: where traffic keeps
one speed its lags mirror as a clock's would, and it is set right as a clock (SUMO's dense
motorway, five seeds, a middle sensor stated 30 / 45 / 100 m off: 84 / 75 / 86 % before,
92 / 87 / 86 % now, 92 % in place). What one offset leaves over where speeds differ is the
learned biases' (on the irregular road, with 30 % trucks, 60 m off: 92.9 -> 91.8 %, where the
learned biases, factors like the position's error, did better). Hence the warning names both.

Lags are gathered within a minute of the kinematic travel times (`CLOCK_REACH`). A clock
minutes or hours off (a time zone or daylight saving time set wrongly) is found first, at any
lag and at either end of the road, by `far_clocks`, and this search measures what it leaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.far_clocks import far_offsets
from roadlink.association.associators.assignment.matching import matched_cost
from roadlink.association.associators.assignment.sensors import travel_time
from roadlink.association.detections import FloatArray, IntArray

# Detections of a segment's near sensor whose pairs are counted, evenly spread over the batch:
# enough that the true pairs' peak stands out, few enough to cost little at 10^6 detections.
CLOCK_SAMPLE = 400
# Fewer detections at either end of a segment and its lag is not searched: a peak of a few
# dozen pairs cannot stand apart from chance, and a paper-size batch (ten a sensor) pays nothing.
CLOCK_LEAST_DETECTIONS = 50
# Seconds searched either side of the kinematic prediction, beyond the segment's typical travel
# time: clocks that no time server keeps in step drift by this much in an hour or so.
CLOCK_REACH = 60.0
# The histogram's bins: 5 % of the typical travel time, at least half a second.
CLOCK_BIN_SHARE = 0.05
CLOCK_BIN_LEAST = 0.5
# The peak's excess over the background (the median bin), in Poisson standard deviations, for a
# lag to count. Free-flowing segments reach 7-12, clock-shifted ones too; queues' lags spread
# and their highest bins reach 2-6 by chance.
CLOCK_SIGNIFICANCE = 7.0
# The offsets set right: at least this share of the segments' typical travel time (and at least
# two bins). Smaller ones stay as the learned biases take them.
CLOCK_LEAST_SHARE = 0.3
# How far the two lags may be from mirroring each other: this share of the offset, and a bin.
CLOCK_MIRROR_TOLERANCE = 0.25
# Smaller offsets, down to this many bins, are set right where matching confirms them
# (`Road.confirms`): each pair's lag costs its square in CLOCK_CONFIRM_TIME bins, its speed
# change its square in CLOCK_CONFIRM_SPEED, a detection left alone half of CLOCK_CONFIRM_GATE,
# and the offset must save CLOCK_CONFIRM_SAVING a sampled detection.
CLOCK_LEAST_BINS = 2.0
CLOCK_CONFIRM_TIME = 0.5
CLOCK_CONFIRM_SPEED = 0.05
CLOCK_CONFIRM_GATE = 9.0
CLOCK_CONFIRM_SAVING = 0.5
# An end sensor's lag is taken for its clock where it fits better than traffic slower by any of
# these times the factor that makes the typical travel time that much longer (`fits_as_clock`).
FIT_FACTORS = tuple(2.0 ** (j / 4) for j in range(-4, 5))


@dataclass(frozen=True)
class Lag:
    """The peak of a segment's lags (s), its significance, its histogram's bin width (s) and the
    segment's typical travel time (s)."""

    seconds: float
    significance: float
    bin_width: float
    typical: float


def clock_offsets(
    positions: FloatArray,
    sorted_time: FloatArray,
    sorted_speed: FloatArray,
    start: IntArray,
    measured: list[Lag | None] | None = None,
) -> FloatArray:
    """Each sensor's clock offset (s; to be taken from its timestamps): 0 where nothing shows
    one. Sensors in road order, each one's detections `sorted_time[start[k]:start[k + 1]]`
    ascending, with their (floored) speeds; `measured`, every segment's lag of these very
    detections where it was measured already (`sensor_order.swapped_pairs`), else None.

    Sensor by sensor, the clearest mirror first (the largest offset), each one set right before
    its neighbours' lags are measured again: a sensor between two others is judged against
    clocks already set right."""
    n = positions.size
    offsets = np.zeros(n)
    if n < 3 or np.diff(start).max() < CLOCK_LEAST_DETECTIONS:
        return offsets
    road = Road(
        positions,
        [sorted_time[start[k] : start[k + 1]].copy() for k in range(n)],
        [sorted_speed[start[k] : start[k + 1]] for k in range(n)],
    )
    # Minutes or hours off first: beyond the reach of the lags below.
    offsets += far_offsets(positions, road.times, road.speeds)
    for k in np.flatnonzero(offsets).tolist():
        road.times[k] -= offsets[k]
    if measured is not None and not offsets.any():
        lags = list(measured)  # set right below, sensor by sensor
    else:
        lags = road.lags(list(range(n - 1)))
    for _ in range(n - 2):
        found = {}
        for k in range(1, n - 1):
            into, out_of = lags[k - 1], lags[k]
            offset = mirrored(into, out_of)
            if into is None or out_of is None or offset is None:
                continue
            if clear(into, out_of, offset) or road.confirms(k, offset):
                found[k] = offset
        if not found:
            break
        k = max(found, key=lambda j: abs(found[j]))
        offsets[k] += found[k]
        road.times[k] -= found[k]
        lags[k - 1], lags[k] = road.lags([k - 1, k])
    for k in (0, n - 1):
        offset = end_offset(road, lags, k)
        if offset is not None:
            offsets[k] += offset
            road.times[k] -= offset
    return offsets


def end_offset(road: Road, lags: list[Lag | None], k: int) -> float | None:
    """The clock offset of the road's first (k = 0) or last sensor, from its one segment's lag
    (`lags`, every segment's), where that lag fits as a clock's (`Road.fits_as_clock`) and the
    neighbour's other segment is on time; else None."""
    segment, other, sign = end_segments(k, road.positions.size)
    lag, beside = lags[segment], lags[other]
    if lag is None or beside is None or not on_time(beside) or on_time(lag):
        return None
    return sign * lag.seconds if road.fits_as_clock(segment, lag.seconds) else None


def end_segments(k: int, n: int) -> tuple[int, int, float]:
    """Of the first (k = 0) or last of n sensors (n >= 3): its one segment, the neighbour's other
    segment, and the sign its clock's offset gives that segment's lags (a late first sensor
    shortens its travel times, a late last one lengthens them)."""
    return (0, 1, -1.0) if k == 0 else (n - 2, n - 3, 1.0)


def on_time(lag: Lag, width: float | None = None) -> bool:
    """Whether a segment's lag is within CLOCK_LEAST_BINS of its bins (`width`, else its own)
    of none."""
    return abs(lag.seconds) < CLOCK_LEAST_BINS * (lag.bin_width if width is None else width)


def clock_warnings(
    positions: FloatArray, offsets: FloatArray | None, stepped: frozenset[int] = frozenset()
) -> list[str]:
    """A sentence for each sensor whose clock was set right, for whoever keeps the detector's
    own clock (the association is not affected); none for the sensors whose clocks `stepped`,
    whose sentences `clock_steps.step_warnings` makes."""
    if offsets is None:
        return []
    n = positions.size
    # An end sensor's offset is its one segment's: it may be the traffic there.
    cause = {True: "its position is", False: "the traffic on its segment takes that long"}
    return [
        f"the sensor at position {positions[k]:g} stamps its detections "
        f"{abs(offsets[k]):.1f} s {'later' if offsets[k] > 0 else 'earlier'} than "
        f"{neighbours_of(k, n)}: its clock is off (or {cause[0 < k < n - 1]}); its times were "
        "set right for the association"
        for k in np.flatnonzero(offsets).tolist()
        if k not in stepped
    ]


def neighbours_of(k: int, n: int) -> str:
    """What a warning calls sensor k's neighbours, of n sensors in road order."""
    return "the sensors either side of it" if 0 < k < n - 1 else "the sensor next to it"


def mirrored(into: Lag | None, out_of: Lag | None) -> float | None:
    """The clock offset of the sensor between two segments, where their lags mirror each other
    (`into` its sensor, `out_of` it); else None."""
    if into is None or out_of is None:
        return None
    offset = 0.5 * (into.seconds - out_of.seconds)
    bin_width = max(into.bin_width, out_of.bin_width)
    if abs(offset) < CLOCK_LEAST_BINS * bin_width:
        return None
    if abs(into.seconds + out_of.seconds) > CLOCK_MIRROR_TOLERANCE * abs(offset) + bin_width:
        return None
    return offset


def clear(into: Lag, out_of: Lag, offset: float) -> bool:
    """Whether an offset is large enough to set right on the lags alone: CLOCK_LEAST_SHARE of
    the segments' typical travel time."""
    return abs(offset) >= CLOCK_LEAST_SHARE * min(into.typical, out_of.typical)


@dataclass(frozen=True)
class Road:
    """The sensors' positions, and each sensor's detection times (ascending) and speeds."""

    positions: FloatArray
    times: list[FloatArray]
    speeds: list[FloatArray]
    # A segment with fewer detections at either end is not searched.
    least_detections: int = CLOCK_LEAST_DETECTIONS

    def lags(self, segments: list[int]) -> list[Lag | None]:
        """The peak of each segment's lags (far time - near time - kinematic travel time) over
        its pairs within reach, where it stands out (`CLOCK_SIGNIFICANCE`); else None. Segment
        k joins sensors k and k + 1. All segments' pairs at once: a segment's own numpy calls
        cost more than its pairs at ten thousand detections."""
        pairs = [self._pairs(k) for k in segments]
        measured = [p for p in pairs if p is not None]
        if not measured:
            return [None] * len(segments)
        lag = np.concatenate([p.lags for p in measured])
        width = np.array([p.width for p in measured])
        reach = np.array([p.reach for p in measured])
        bins = np.ceil(2 * reach / width).astype(np.int64)
        row = np.repeat(np.arange(len(measured)), [p.lags.size for p in measured])
        index = np.floor((lag + reach[row]) / width[row]).astype(np.int64)
        inside = (index >= 0) & (index < bins[row])
        first_bin = np.cumsum(bins) - bins
        histograms = np.bincount((first_bin[row] + index)[inside], minlength=int(bins.sum()))
        peaks = iter(
            _peak(p, histograms[first_bin[r] : first_bin[r] + bins[r]])
            for r, p in enumerate(measured)
        )
        return [None if p is None else next(peaks) for p in pairs]

    def confirms(self, k: int, offset: float) -> bool:
        """Whether matching the sampled detections either side of sensor k to their neighbours'
        by time and speed costs clearly less with sensor k's clock `offset` seconds late than
        with it on time. A lag's peak may sit a headway off where traffic is dense (the
        neighbouring vehicles' comb), mirrored by chance: then the offset pairs each vehicle with
        its neighbour, whose speed differs, and matching rejects it."""
        saving, count = 0.0, 0
        for segment, sign in ((k - 1, 1.0), (k, -1.0)):
            matched = self._matched_costs(segment, self._gathered(segment), [0.0, sign * offset])
            if matched is None:
                return False
            (on_time, shifted), sampled = matched
            saving += on_time - shifted
            count += sampled
        return saving >= CLOCK_CONFIRM_SAVING * count

    def fits_as_clock(self, segment: int, shift: float) -> bool:
        """Whether matching the segment's sampled pairs by time and speed costs clearly less
        (CLOCK_CONFIRM_SAVING a sampled detection) with every travel time `shift` seconds longer
        than its kinematic prediction, as a clock at one end makes them, than both on time and
        longer by any one factor (FIT_FACTORS: the factor that makes the typical travel time
        `shift` longer, and others around it, since the lags of a factor peak where the
        quickest vehicles are), as traffic that takes longer over the segment makes them."""
        gathered = self._gathered(segment)
        if gathered is None:
            return False
        near_speed = gathered.near_speed[gathered.which]
        far_speed = self.speeds[segment + 1][gathered.at]
        gap = float(self.positions[segment + 1] - self.positions[segment])
        kinematic = travel_time(gap, near_speed, far_speed)
        share = shift / gathered.pairs.typical
        by_factor = [share * scale * kinematic for scale in FIT_FACTORS]
        matched = self._matched_costs(segment, gathered, [shift, 0.0, *by_factor])
        if matched is None:
            return False
        (as_clock, *others), sampled = matched
        return min(others) - as_clock >= CLOCK_CONFIRM_SAVING * sampled

    def _matched_costs(
        self, segment: int, gathered: Gathered | None, centres: list[float | FloatArray]
    ) -> tuple[list[float], int] | None:
        """The cost of matching the segment's sampled pairs near each of `centres` (a lag in
        seconds, or one a pair), each pair's lag costing its square off the centre in
        CLOCK_CONFIRM_TIME bins and its speed change its square in CLOCK_CONFIRM_SPEED, a
        detection left alone half of CLOCK_CONFIRM_GATE; and how many sampled detections the
        segment has (None where it has too few detections to be searched: no `gathered`)."""
        if gathered is None:
            return None
        lags, width = gathered.pairs.lags, gathered.pairs.width
        change = gathered.speed_change(self.speeds[segment], self.speeds[segment + 1])
        window = 3.0 * width
        near = np.zeros(lags.size, dtype=bool)
        for centre in centres:
            near |= np.abs(lags - centre) <= window
        left, right = gathered.which[near], gathered.at[near]
        speed_cost = np.square(change[near] / CLOCK_CONFIRM_SPEED)
        spread = CLOCK_CONFIRM_TIME * width
        costs = [
            matched_cost(
                left,
                right,
                np.square((lags[near] - np.broadcast_to(centre, lags.shape)[near]) / spread)
                + speed_cost,
                CLOCK_CONFIRM_GATE,
            )
            for centre in centres
        ]
        return costs, int(np.unique(gathered.which).size)

    def _pairs(self, k: int) -> SegmentPairs | None:
        """Segment k's sampled detections' lags to the far sensor's detections within reach of
        their arrival at their own speed (None with too few detections at either end)."""
        gathered = self._gathered(k)
        return None if gathered is None else gathered.pairs

    def _gathered(self, k: int) -> Gathered | None:
        """Segment k's sampled pairs, as `_pairs` and `confirms` read them."""
        near_time, near_speed = self.times[k], self.speeds[k]
        far_time, far_speed = self.times[k + 1], self.speeds[k + 1]
        if min(near_time.size, far_time.size) < self.least_detections:
            return None
        gap = float(self.positions[k + 1] - self.positions[k])
        typical = float(travel_time(gap, np.median(near_speed), np.median(far_speed)))
        reach = CLOCK_REACH + typical
        if near_time.size > CLOCK_SAMPLE:
            sample = np.linspace(0, near_time.size - 1, CLOCK_SAMPLE).astype(np.int64)
            near_time, near_speed = near_time[sample], near_speed[sample]
        expected = near_time + gap / near_speed
        lo = np.searchsorted(far_time, expected - reach)
        count = np.searchsorted(far_time, expected + reach) - lo
        which = np.repeat(np.arange(near_time.size), count)
        at = np.arange(which.size) + np.repeat(lo - (np.cumsum(count) - count), count)
        lags = far_time[at] - near_time[which]
        lags -= travel_time(gap, near_speed[which], far_speed[at])
        width = max(CLOCK_BIN_SHARE * typical, CLOCK_BIN_LEAST)
        return Gathered(SegmentPairs(lags, reach, width, typical), which, at, near_speed)


@dataclass(frozen=True)
class Gathered:
    """A segment's pairs (`SegmentPairs`), and which sampled near detection (of `near_speed`,
    the sample's speeds) and which far detection each joins."""

    pairs: SegmentPairs
    which: IntArray
    at: IntArray
    near_speed: FloatArray

    def speed_change(self, near_all: FloatArray, far_all: FloatArray) -> FloatArray:
        """Each pair's change of log speed, each reading against its sensor's median (of all
        its speeds, `near_all` and `far_all`): near 0 for a vehicle's own two readings."""
        change: FloatArray = np.log(far_all[self.at] / np.median(far_all)) - np.log(
            self.near_speed[self.which] / np.median(near_all)
        )
        return change


@dataclass(frozen=True)
class SegmentPairs:
    """A segment's pairs' lags (s), the reach they were gathered within either side (s), its
    histogram's bin width (s) and its typical travel time (s)."""

    lags: FloatArray
    reach: float
    width: float
    typical: float


def _peak(pairs: SegmentPairs, histogram: npt.NDArray[np.int64]) -> Lag | None:
    """The histogram's highest bin, where it stands out: the mean of the lags in it and the bins
    either side."""
    background = max(float(np.median(histogram)), 1.0)
    peak = int(np.argmax(histogram))
    significance = (histogram[peak] - background) / np.sqrt(background)
    if significance < CLOCK_SIGNIFICANCE:
        return None
    centre = -pairs.reach + (peak + 0.5) * pairs.width
    near = np.abs(pairs.lags - centre) <= 1.5 * pairs.width
    return Lag(float(np.mean(pairs.lags[near])), float(significance), pairs.width, pairs.typical)
