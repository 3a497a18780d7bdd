"""Sensors' clocks off by minutes or hours: a time zone or daylight saving time set wrongly, a
clock set by hand, a detector that came back from a power cut at the wrong time.

`clocks` finds a sensor's offset within a minute of the kinematic travel times, from the lags of
pairs of detections gathered within that reach: wider, their background would bury the true
pairs' peak, and their number would grow with every minute searched. A sensor an hour off
stamps its detections outside the other sensors' time span altogether, and one two minutes
off inside it but beyond that reach: each of its vehicles was then linked to another vehicle,
or to none (SUMO's free flow with a middle sensor 2 minutes late: 82.8 % without lane or
length over five seeds, an hour late 89.0 %, on time 98.5 %).

So each segment's lag is first searched at any distance: every detection of the near sensor
moved on by its own kinematic travel time, and the far sensor's detections, are
counted in bins of the fine search's width, and the two series' cross-correlation (by FFT: the
count of pairs at every lag at once) peaks at the far clock's offset from the near one, above
the background of unrelated pairs. A sensor between two segments whose peaks stand out and
mirror each other beyond the fine search's reach is set right by their half difference; the
first or last sensor, whose one segment's peak stands out as far, by that peak (where traffic
flows alike at both of its sensors and the segment beside it keeps time). The fine search
(`clocks.clock_offsets`) then measures what is left. A segment whose far sensor's first and
last detections come within a minute of a travel time after the near sensor's has no clock
far off, and is not correlated: every sensor of a batch sees its window open and close.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from roadlink.association.associators.assignment.sensors import travel_time
from roadlink.association.detections import FloatArray

# A far offset is one past this many seconds (the fine search's reach, `clocks.CLOCK_REACH`),
# and past this many of its segments' typical travel times: in a crawl (1.6 m/s past sensors
# 200 m apart), vehicles pass neighbouring sensors in waves, moments apart, and the
# correlation peaks a kinematic travel time (125 s) short of it, clearly.
FAR_LEAST = 60.0
FAR_LEAST_TRAVEL_TIMES = 2.0
# The correlation's peak must stand this many Poisson standard deviations above its median
# within FAR_BACKGROUND seconds, or FAR_BACKGROUND_TRAVEL_TIMES typical travel times, either
# side (the fine search's significance, `clocks.CLOCK_SIGNIFICANCE`, and reach).
FAR_SIGNIFICANCE = 7.0
FAR_BACKGROUND = 60.0
FAR_BACKGROUND_TRAVEL_TIMES = 4.0
# Bins of this share of the segment's typical travel time, at least FAR_BIN_LEAST seconds (as
# the lags' search's: wider, dense traffic's peak sinks into its background, a passage every
# 0.8 s), and coarser where the series would be longer than FAR_MOST_BINS (a batch of months).
FAR_BIN_SHARE = 0.05
FAR_BIN_LEAST = 0.5
FAR_MOST_BINS = 1 << 22
# An end sensor's far lag counts where its segment's two median speeds are within this ratio
# (a clock moves no speed), and the segment beside it peaks within FAR_KEPT of a travel time.
FAR_SPEED_RATIO = 1.25
FAR_KEPT = 0.5
# Two lags mirror where their sum is within this share of the offset, and two bins.
FAR_MIRROR_TOLERANCE = 0.25
# Pairs are counted within this many classes of speed, each a share of the near sensor's.
FAR_SPEED_CLASSES = 3
# Fewer detections at either end of a segment and its lag is not searched.
FAR_LEAST_DETECTIONS = 50


def far_offsets(
    positions: FloatArray, times: list[FloatArray], speeds: list[FloatArray]
) -> FloatArray:
    """Each sensor's clock offset (s; to be taken from its times) where it is far (`Lag.far`)
    and the correlations show it; 0 elsewhere. `times[k]` are sensor k's detection times
    (ascending), `speeds[k]` their speeds. With two sensors, which one is off cannot be told."""
    n = positions.size
    offsets = np.zeros(n)
    if n < 3:
        return offsets
    road = FarRoad(positions, times, speeds, np.array([np.median(v) for v in speeds]))
    lags = [road.lag(k) for k in range(n - 1)]
    for k in range(n):
        offset = sensor_offset(lags, k)
        if offset is not None:
            offsets[k] = offset
    return offsets


class Lag(NamedTuple):
    """A segment's lag (s) where its correlation peaks clearly, the width of its bins (s) and
    its typical travel time (s)."""

    seconds: float
    width: float
    typical: float
    flowing: bool  # the median speeds at its two sensors within FAR_SPEED_RATIO

    def far(self) -> bool:
        """Whether the lag is past FAR_LEAST seconds and FAR_LEAST_TRAVEL_TIMES travel times."""
        return abs(self.seconds) > max(FAR_LEAST, FAR_LEAST_TRAVEL_TIMES * self.typical)

    def keeps_time(self) -> bool:
        """Whether the lag is within FAR_KEPT of a travel time (and two bins) of none."""
        return abs(self.seconds) <= FAR_KEPT * self.typical + 2 * self.width


def sensor_offset(lags: Sequence[Lag | None], k: int) -> float | None:
    """Sensor k's clock offset as its segments' lags tell it (None where they do not): a sensor
    late by d adds d to the lag into it and takes d from the lag out of it. The first or last
    sensor has one segment, whose lag counts where traffic flows alike at its two sensors and
    the segment beside it clearly keeps time (`Lag.keeps_time`): a far lag that both show is
    the middle sensor's, and where a queue begins its waves can set a segment's peak far
    (SUMO's stop-and-go numbered backwards: the last sensor, at 16 m/s beside one at 2.5 m/s,
    138 s "early", the segment beside it a kinematic travel time short)."""
    last = len(lags)
    if 0 < k < last:
        into, out_of = lags[k - 1], lags[k]
        if into is None or out_of is None or not (into.far() and out_of.far()):
            return None
        offset = 0.5 * (into.seconds - out_of.seconds)
        width = max(into.width, out_of.width)
        tolerance = FAR_MIRROR_TOLERANCE * abs(offset) + 2 * width
        return offset if abs(into.seconds + out_of.seconds) <= tolerance else None
    own, beside = (lags[0], lags[1]) if k == 0 else (lags[-1], lags[-2])
    if own is None or not own.far() or not own.flowing or beside is None:
        return None
    if not beside.keeps_time():
        return None
    return -own.seconds if k == 0 else own.seconds


class FarRoad(NamedTuple):
    """The sensors' positions, each one's detection times (ascending), speeds and median speed."""

    positions: FloatArray
    times: list[FloatArray]
    speeds: list[FloatArray]
    medians: FloatArray

    def lag(self, k: int) -> Lag | None:
        """Segment k's lag (far sensor's times less the near sensor's moved on by their
        kinematic travel times) where its correlation peaks clearly (`Lag`), or none where its
        sensors' windows open and close alike; else None."""
        near, far = self.times[k], self.times[k + 1]
        if min(near.size, far.size) < FAR_LEAST_DETECTIONS:
            return None
        gap = float(self.positions[k + 1] - self.positions[k])
        typical = float(travel_time(gap, self.medians[k], self.medians[k + 1]))
        ratio = float(self.medians[k + 1] / self.medians[k])
        flowing = 1.0 / FAR_SPEED_RATIO <= ratio <= FAR_SPEED_RATIO
        # Where the far sensor's first and last detections come within FAR_LEAST of a travel
        # time after the near one's, the batch's window opens and closes alike for both: no
        # clock is far off, and the correlation (most of a second for the 49 segments of 10^6
        # detections over 16 hours) is not worked out.
        ends = np.array([far[0] - near[0], far[-1] - near[-1]]) - typical
        if np.all(np.abs(ends) <= FAR_LEAST):
            return Lag(0.0, FAR_BIN_LEAST, typical, flowing)
        arrival = near + gap / self.speeds[k]
        lo = min(float(arrival.min()), float(far.min()))
        span = max(float(arrival.max()), float(far.max())) - lo
        if not np.isfinite(span):
            return None
        width = max(FAR_BIN_SHARE * typical, FAR_BIN_LEAST, span / FAR_MOST_BINS)
        bins = int(span // width) + 1
        size = 1 << int(np.ceil(np.log2(2 * bins)))
        # A driver keeps its place among the speeds around it: pairs are counted within each
        # third of the speeds (relative to each sensor's median), which keeps most true pairs
        # and a third of the unrelated ones (SUMO's faulty loops, a sensor an hour late: the
        # peak 6.9 deviations high over all pairs, 9.4 so).
        near_class = np.log(self.speeds[k] / self.medians[k])
        edges = np.quantile(near_class, np.linspace(0.0, 1.0, FAR_SPEED_CLASSES + 1)[1:-1])
        near_class = np.searchsorted(edges, near_class)
        far_class = np.searchsorted(edges, np.log(self.speeds[k + 1] / self.medians[k + 1]))
        spectrum = np.zeros(size // 2 + 1, dtype=np.complex128)
        for c in range(FAR_SPEED_CLASSES):
            a = np.bincount(((arrival[near_class == c] - lo) // width).astype(np.int64))
            b = np.bincount(((far[far_class == c] - lo) // width).astype(np.int64))
            spectrum += np.conj(np.fft.rfft(a, size)) * np.fft.rfft(b, size)
        # correlation[L] = sum_i a[i] b[i + L], L from -(bins - 1) to bins - 1.
        full = np.fft.irfft(spectrum, size)
        correlation = np.rint(np.r_[full[size - bins + 1 :], full[:bins]])
        # The background is the unrelated pairs' count about the peak (the median within
        # FAR_BACKGROUND of it): further off it falls with the series' overlap, to none where a
        # sensor an hour off shares no time with its neighbour.
        peak = int(np.argmax(correlation))
        reach = int(max(FAR_BACKGROUND, FAR_BACKGROUND_TRAVEL_TIMES * typical) / width)
        around = correlation[max(peak - reach, 0) : peak + reach + 1]
        background = max(float(np.median(around)), 1.0)
        if (correlation[peak] - background) / np.sqrt(background) < FAR_SIGNIFICANCE:
            return None
        return Lag(float((peak - (bins - 1)) * width), width, typical, flowing)
