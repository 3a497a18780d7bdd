"""Sensors' clocks that step part-way through a batch, found and set right before anything is
linked.

A detector's clock can jump while it reports: a time server corrects it, it restarts and
takes its time again, daylight saving time begins. From then on every travel time into it is
longer by the step and every travel time out of it shorter; `clocks.clock_offsets` takes one
offset a sensor for the whole batch, and a step left either half wrong (SUMO's dense
motorway without lane and length, the middle sensor stepping 5 s to an hour late half-way,
five seeds: 83.7-86.1 % of the detections right against 91.8 % on time; free flow 91.0-93.6 %
against 98.6 %).

So once every sensor's clock is set right as a whole, three things are looked for. A sensor set
right as a whole may have been set by one part's offset: it stepped where its other part fits
its neighbours as reported. Then the batch is cut at its middle time and each half searched: a
step of minutes or hours where each half's correlations (`far_clocks.far_offsets`) find a far
offset in one half and none in the other; a smaller one where one half's segment lags
(`Road.lags`, both halves' segments at once) are on time and the other's show an offset, its
two segments' lags mirroring it as `clocks` asks of one (a peak 7 Poisson deviations high, and
30 % of a travel time or confirmed by matching), or one segment's alone where matching confirms
it (`_offset`). Where in the batch it stepped is where its detections stop fitting their
neighbours at the first offset and start fitting them at the second (`stepped_places`): each
detection's best pair at the sensors either side, where its own speed says it would be, is
scored under both offsets, and the step falls where the running sum of the differences is
lowest. A step is kept where the detections fit their neighbours with it (`_fits`), leaving
STEP_LEAST_SIDE of them on either side, and looked for only where traffic flows at the sensor
and its neighbours. The first and the last sensor have one segment, and nothing to mirror: a
step there is its segment's lag on time in one half and off in the other, where it fits as a
clock's and not as slower traffic's (`clocks.Road.fits_as_clock`) and the neighbour's other
segment is on time in both halves (`_end_step_offsets`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from roadlink.association.associators.assignment.clocks import (
    CLOCK_BIN_LEAST,
    CLOCK_BIN_SHARE,
    CLOCK_CONFIRM_GATE,
    CLOCK_CONFIRM_SAVING,
    CLOCK_CONFIRM_SPEED,
    CLOCK_CONFIRM_TIME,
    CLOCK_LEAST_BINS,
    CLOCK_LEAST_DETECTIONS,
    CLOCK_MIRROR_TOLERANCE,
    Lag,
    Road,
    clear,
    end_segments,
    neighbours_of,
    on_time,
)
from roadlink.association.associators.assignment.far_clocks import far_offsets
from roadlink.association.associators.assignment.params import FLOWING_SHARE
from roadlink.association.associators.assignment.sensors import travel_time
from roadlink.association.detections import FloatArray, IntArray

# A detection's neighbours are looked for within this many of the lags' bins of where its speed
# says they would be.
STEP_FIT_BINS = 3.0
# Steps are looked for only where traffic flows at the sensor and its neighbours (a
# median speed of at least `params.FLOWING_SHARE` of the fastest sensor's): in a crawl vehicles
# pass neighbouring sensors in waves, and a half's lags mirrored an "offset" of one travel time
# (SUMO, faulty loops in a queue at 2.7 m/s: a step of 91 s set at a sensor whose clock kept
# time, 84 -> 76 %).
# A step leaves at least this many of the sensor's detections on either side (what a half's lags
# need at each end of a segment): nearer the batch's edges a few detections that fit poorly,
# their partners outside the window, looked like a step from a clock set right as a whole.
STEP_LEAST_SIDE = CLOCK_LEAST_DETECTIONS // 2
# A step is taken where the detections fit their neighbours with it within this share of what
# leaving each alone at both neighbours costs, on average (2 half-gates: CLOCK_CONFIRM_GATE).
# Steps set on SUMO's dense and free-flowing traffic fit within 0.1-0.2 of it; a road numbered
# against the traffic "fits" a step at 0.8.
STEP_FIT_SHARE = 0.5


@dataclass(frozen=True)
class ClockStep:
    """Sensor `sensor`'s clock, set right as a whole, was still `before` seconds late until it
    stepped, about its report stamped `time` (once set right as a whole), and `after` seconds
    late from then on: `later` are the places (among its detections in time order) stamped
    after the step."""

    sensor: int
    time: float
    before: float
    after: float
    later: IntArray = field(repr=False)


def clock_steps(
    positions: FloatArray,
    times: list[FloatArray],
    speeds: list[FloatArray],
    set_right: FloatArray | None = None,
) -> list[ClockStep]:
    """The sensors whose clocks stepped part-way through the batch, each sensor's detection
    times (ascending, every clock already set right as a whole: by `set_right` seconds, where
    given) and speeds given in road order."""
    n = positions.size
    if n < 3 or max(t.size for t in times) < CLOCK_LEAST_DETECTIONS:
        return []
    parts = _parts(times)
    halves = _halves(positions, times, speeds, parts)
    far = _far_steps(positions, times, speeds, parts)
    typical = np.array([np.median(v) if v.size else 0.0 for v in speeds])
    flowing = typical >= FLOWING_SHARE * typical.max()
    whole = Road(positions, times, speeds)
    steps, found = [], {}
    for k in range(n):
        if not flowing[max(k - 1, 0) : k + 2].all():
            continue
        if set_right is not None and set_right[k] != 0.0:
            step = _set_right_in_part(whole, speeds, k, float(set_right[k]))
            if step is not None:
                steps.append(step)
                continue
        shown = far.get(k) or (_step_offsets if 0 < k < n - 1 else _end_step_offsets)(halves, k)
        if shown is not None:
            found[k] = shown
    stepped = {step.sensor for step in steps}
    for k, (before, after, width, alone) in found.items():
        # A step one segment's lag alone showed may be its neighbour's, across that segment.
        if alone and (stepped | found.keys()) & {k - 1, k + 1}:
            continue
        step = _placed(whole, k, before, after, width)
        if step is not None:
            steps.append(step)
    return sorted(steps, key=lambda step: step.sensor)


def _set_right_in_part(
    road: Road, speeds: list[FloatArray], k: int, set_right: float
) -> ClockStep | None:
    """Sensor k's step, where its clock was set right as a whole by `set_right` seconds, the
    offset of one part of the batch (the lags' highest peak, or the correlation's, was that
    part's), and its other part, before or after, fits its neighbours as reported."""
    width = bin_width(road.positions, speeds, k)
    for before, after in ((-set_right, 0.0), (0.0, -set_right)):
        step = _placed(road, k, before, after, width)
        if step is not None:
            return step
    return None


def bin_width(positions: FloatArray, speeds: list[FloatArray], k: int) -> float:
    """The lags' bin width (`clocks.CLOCK_BIN_SHARE` of the typical travel time, at least
    `clocks.CLOCK_BIN_LEAST`) of sensor k's segments, their mean length at its median speed."""
    ends = positions[max(k - 1, 0)], positions[min(k + 1, positions.size - 1)]
    gap = float(ends[1] - ends[0]) / len(neighbouring_sensors(k, positions.size))
    median_speed = float(np.median(speeds[k]))
    typical = float(travel_time(gap, median_speed, median_speed))
    return max(CLOCK_BIN_SHARE * typical, CLOCK_BIN_LEAST)


def _parts(times: list[FloatArray]) -> list[list[slice]]:
    """The batch cut at its middle time: each sensor's detections in either half."""
    middle = float(np.median(np.concatenate(times)))
    cut = [int(np.searchsorted(t, middle)) for t in times]
    return [[slice(None, c) for c in cut], [slice(c, None) for c in cut]]


def _halves(
    positions: FloatArray,
    times: list[FloatArray],
    speeds: list[FloatArray],
    parts: list[list[slice]],
) -> list[tuple[Road, list[Lag | None]]]:
    """Each half's road (its segments searched from half the detections a whole batch's need)
    and every segment's lag in it."""
    halves = []
    for part in parts:
        half = Road(
            positions,
            [t[p] for t, p in zip(times, part, strict=True)],
            [v[p] for v, p in zip(speeds, part, strict=True)],
            STEP_LEAST_SIDE,
        )
        halves.append((half, half.lags(list(range(positions.size - 1)))))
    return halves


def _far_steps(
    positions: FloatArray,
    times: list[FloatArray],
    speeds: list[FloatArray],
    parts: list[list[slice]],
) -> dict[int, tuple[float, float, float, bool]]:
    """The sensors whose clocks stepped by minutes or hours (beyond the lags' reach: daylight
    saving time, a clock taken again by hand), each with `_step_offsets`'s numbers: a far
    offset (`far_clocks.far_offsets`) in one half and none in the other."""
    if any(t[p].size == 0 for part in parts for t, p in zip(times, part, strict=True)):
        return {}
    first, second = (
        far_offsets(
            positions,
            [t[p] for t, p in zip(times, part, strict=True)],
            [v[p] for v, p in zip(speeds, part, strict=True)],
        )
        for part in parts
    )
    return {
        k: (float(first[k]), float(second[k]), bin_width(positions, speeds, k), False)
        for k in np.flatnonzero((first == 0.0) != (second == 0.0)).tolist()
    }


def _step_offsets(
    halves: list[tuple[Road, list[Lag | None]]], k: int
) -> tuple[float, float, float, bool] | None:
    """Sensor k's offsets before and after a step (s), the lags' bin width, and whether one
    segment's lag alone showed the step; None where its halves show none."""
    (first_half, first_lags), (second_half, second_lags) = halves
    first_shown = _offset(first_half, first_lags[k - 1], first_lags[k], k)
    second_shown = _offset(second_half, second_lags[k - 1], second_lags[k], k)
    if first_shown is None or second_shown is None:
        return None
    first, first_on_time, first_alone = first_shown
    second, second_on_time, second_alone = second_shown
    lags = [lag for lag in (*first_lags[k - 1 : k + 1], *second_lags[k - 1 : k + 1]) if lag]
    width = max(lag.bin_width for lag in lags)
    # A clock steps from one offset to another, and the clocks were set right as a whole first
    # (by one of the two, where the halves hold them alike): one half is on time. Where
    # neither is, something else moves the lags (a sensor reading speeds in km/h, a road
    # numbered against the traffic).
    if first_on_time == second_on_time or abs(second - first) < CLOCK_LEAST_BINS * width:
        return None
    # The half on time keeps its times; the step is the difference the halves measured (a
    # segment's bias moves both halves' lags alike).
    before, after = (0.0, second - first) if first_on_time else (first - second, 0.0)
    return before, after, width, first_alone or second_alone


def _end_step_offsets(
    halves: list[tuple[Road, list[Lag | None]]], k: int
) -> tuple[float, float, float, bool] | None:
    """`_step_offsets` of the road's first (k = 0) or last sensor, from its one segment: its
    lag on time in one half, and in the other off by at least CLOCK_LEAST_BINS and fitting as a
    clock's (`Road.fits_as_clock`: every travel time longer by the same seconds, not by one
    factor as traffic that slows would make them); the neighbour's other segment on time in
    both halves (else the step may be the neighbour's)."""
    segment, other, sign = end_segments(k, halves[0][0].positions.size)
    shown = []
    for half, lags in halves:
        lag, beside = lags[segment], lags[other]
        if lag is None or beside is None or not on_time(beside):
            return None
        shown.append((half, lag))
    (first_half, first), (second_half, second) = shown
    width = max(first.bin_width, second.bin_width)
    if on_time(first, width) == on_time(second, width):
        return None
    off_half, off = (second_half, second) if on_time(first, width) else (first_half, first)
    if not off_half.fits_as_clock(segment, off.seconds):
        return None
    if off is second:
        return 0.0, sign * (second.seconds - first.seconds), width, False
    return sign * (first.seconds - second.seconds), 0.0, width, False


def neighbouring_sensors(k: int, n: int) -> list[int]:
    """Sensor k's neighbours, of n sensors in road order."""
    return [j for j in (k - 1, k + 1) if 0 <= j < n]


def _placed(road: Road, k: int, before: float, after: float, width: float) -> ClockStep | None:
    """Sensor k's step from `before` to `after` seconds late, placed among its detections and
    its offset measured finer, where the detections fit it (`_fits`); else None."""
    size = road.times[k].size
    later = stepped_places(road, k, before, after, width)
    if not 0 < later.size < size:
        return None
    # A lag's peak is read to a bin or so (one segment's may lean on the comb of dense
    # traffic), and the misfit measures finer: the offset off time set where its detections
    # fit best, within two bins, and the step placed again.
    if before == 0.0:
        after = _best_offset(road, k, after, width, later)
    else:
        before = _best_offset(road, k, before, width, np.setdiff1d(np.arange(size), later))
    misfit = _misfits(road, k, before, after, width)
    later = _split(road.times[k], before, after, misfit)
    fits = STEP_LEAST_SIDE <= later.size <= size - STEP_LEAST_SIDE
    if fits and _fits(misfit, later, len(neighbouring_sensors(k, road.positions.size))):
        return ClockStep(k, float(road.times[k][later[0]]), before, after, later)
    return None


def _fits(misfit: tuple[FloatArray, FloatArray], later: IntArray, neighbours: int) -> bool:
    """Whether a sensor's detections, with their `misfit`s at the offsets before and after a
    step (`_misfits`), fit their `neighbours` (sensors: 1 or 2) with the step stamping `later`:
    each side better at its own offset than at the other's by CLOCK_CONFIRM_SAVING a detection
    (as `clocks` asks of a small offset), and all of them fitting, on average, within
    STEP_FIT_SHARE of what leaving each alone at its neighbours costs (a road whose lags
    something else moves, numbered against the traffic, fits neither way)."""
    earlier = np.ones(misfit[0].size, dtype=bool)
    earlier[later] = False
    saved_before = float(np.mean(misfit[1][earlier] - misfit[0][earlier]))
    saved_after = float(np.mean(misfit[0][later] - misfit[1][later]))
    kept = float(np.mean(np.where(earlier, misfit[0], misfit[1])))
    return (
        min(saved_before, saved_after) >= CLOCK_CONFIRM_SAVING
        and kept <= STEP_FIT_SHARE * 0.5 * CLOCK_CONFIRM_GATE * neighbours
    )


def _offset(
    road: Road, into: Lag | None, out_of: Lag | None, k: int
) -> tuple[float, bool, bool] | None:
    """Sensor k's offset in `road` (one half of the batch), whether that is on time (its
    segments' lags mirror less than CLOCK_LEAST_BINS of an offset, whatever else moves them
    both), and whether one segment's lag alone showed it: the mirrored offset where they mirror
    one clearly (as `clocks` sets one right), else one segment's own where matching confirms
    it; None where they show neither."""
    if into is None or out_of is None:
        return None
    width = max(into.bin_width, out_of.bin_width)
    offset = 0.5 * (into.seconds - out_of.seconds)
    if abs(offset) < CLOCK_LEAST_BINS * width:
        return offset, True, False
    if abs(into.seconds + out_of.seconds) <= CLOCK_MIRROR_TOLERANCE * abs(offset) + width:
        confirmed = clear(into, out_of, offset) or road.confirms(k, offset)
        return (offset, False, False) if confirmed else None
    # In dense traffic one segment's highest bin may sit on the comb of neighbouring vehicles
    # while the other's stands at the offset: each segment's own offset, where matching
    # confirms it.
    for alone in (into.seconds, -out_of.seconds):
        if abs(alone) >= CLOCK_LEAST_BINS * width and road.confirms(k, alone):
            return alone, False, True
    return None


def stepped_places(road: Road, k: int, before: float, after: float, width: float) -> IntArray:
    """Which of sensor k's detections (places in time order) its clock stamped after it
    stepped from `before` to `after` seconds late: those from the place where they start to fit
    their neighbours better at `after` than at `before` (`_misfit`). A clock that stepped back
    stamped some of the passages after the step earlier than some before it: within that
    overlap each detection takes the offset it fits better."""
    return _split(road.times[k], before, after, _misfits(road, k, before, after, width))


def _misfits(
    road: Road, k: int, before: float, after: float, width: float
) -> tuple[FloatArray, FloatArray]:
    """Sensor k's detections' misfits at `before` and at `after` (`_misfit`)."""
    return _misfit(road, k, before, width), _misfit(road, k, after, width)


def _split(
    time: FloatArray, before: float, after: float, misfit: tuple[FloatArray, FloatArray]
) -> IntArray:
    """`stepped_places` of a sensor's detection `time`s, from their `misfit`s (`_misfits`)."""
    gain = np.concatenate([[0.0], np.cumsum(misfit[1] - misfit[0])])
    # Detections before the place keep `before`, the rest take `after`: the total misfit is
    # the before-misfits' sum plus gain[-1] - gain[place], lowest where gain[place] is highest.
    place = int(np.argmax(gain))
    later = np.arange(time.size) >= place
    if after < before and place < time.size:
        overlap = np.abs(time - time[place]) <= before - after
        later[overlap] = misfit[1][overlap] < misfit[0][overlap]
    return np.flatnonzero(later)


def _misfit(road: Road, k: int, offset: float, width: float) -> FloatArray:
    """Each of sensor k's detections' misfit with `offset` taken from its times: at each
    neighbouring sensor (one at the road's ends), the least cost of a detection where its own
    speed says that detection would be (`_nearby`), at most half of CLOCK_CONFIRM_GATE (what
    leaving it alone costs). A neighbour's time alone fits any offset in dense traffic, a
    headway or two off."""
    alone = 0.5 * CLOCK_CONFIRM_GATE
    total = np.zeros(road.times[k].size)
    for j in neighbouring_sensors(k, road.positions.size):
        which, _, cost = _nearby(road, k, j, offset, width)
        least = np.full(total.size, alone)
        np.minimum.at(least, which, cost)
        total += least
    return total


def _best_offset(road: Road, k: int, offset: float, width: float, places: IntArray) -> float:
    """The offset within CLOCK_LEAST_BINS bins of `offset`, in tenths of a bin, at which sensor
    k's detections `places` fit their neighbours best (`_misfit`)."""
    candidates = offset + width * np.linspace(-CLOCK_LEAST_BINS, CLOCK_LEAST_BINS, 41)
    fits = [float(_misfit(road, k, c, width)[places].sum()) for c in candidates]
    return float(candidates[int(np.argmin(fits))])


def _nearby(
    road: Road, k: int, j: int, offset: float, width: float
) -> tuple[IntArray, FloatArray, FloatArray]:
    """Pairs of sensor k's detections (`offset` taken from their times) with neighbour j's
    within STEP_FIT_BINS bins of where their own speeds say they would be: which of k's, the
    time error (s), and the cost `Road.confirms` gives a pair (the time error in
    CLOCK_CONFIRM_TIME bins of `width`, the change of speed, each against its sensor's median,
    in CLOCK_CONFIRM_SPEED, both squared)."""
    time, speed = road.times[k] - offset, road.speeds[k]
    expected = time + (road.positions[j] - road.positions[k]) / speed
    reach = STEP_FIT_BINS * width
    lo = np.searchsorted(road.times[j], expected - reach)
    count = np.searchsorted(road.times[j], expected + reach) - lo
    which = np.repeat(np.arange(time.size), count)
    at = np.arange(which.size) + np.repeat(lo - (np.cumsum(count) - count), count)
    error = road.times[j][at] - expected[which]
    return which, error, pair_cost(error, speed_change(road, k, j, which, at), width)


def speed_change(road: Road, k: int, j: int, which: IntArray, at: IntArray) -> FloatArray:
    """The change of speed from sensor k's detections `which` to neighbour j's `at`, each
    reading against its sensor's median (log)."""
    change: FloatArray = np.log(road.speeds[j][at] / np.median(road.speeds[j])) - np.log(
        road.speeds[k][which] / np.median(road.speeds[k])
    )
    return change


def pair_cost(error: FloatArray, change: FloatArray, width: float) -> FloatArray:
    """What a pair costs where its time error is `error` (s) and its speed change `change`: the
    error in CLOCK_CONFIRM_TIME bins of `width` and the change in CLOCK_CONFIRM_SPEED, both
    squared, as `Road.confirms` costs a pair."""
    cost: FloatArray = np.square(error / (CLOCK_CONFIRM_TIME * width)) + np.square(
        change / CLOCK_CONFIRM_SPEED
    )
    return cost


def step_warnings(
    positions: FloatArray, offsets: FloatArray | None, steps: list[ClockStep]
) -> list[str]:
    """A sentence for each sensor whose clock stepped (`offsets`, what `clocks` took from each
    sensor's times as a whole), for whoever keeps the detector's own clock."""
    if offsets is None:
        offsets = np.zeros(positions.size)
    beside = [neighbours_of(step.sensor, positions.size) for step in steps]
    return [
        f"the sensor at position {positions[step.sensor]:g} stamps its detections "
        f"{_lateness(offsets[step.sensor] + step.before, them)} until its report "
        f"stamped {step.time + offsets[step.sensor]:g}, and "
        f"{_lateness(offsets[step.sensor] + step.after, them)} from that report on: its "
        "clock stepped while it reported; its times were set right for the association"
        for step, them in zip(steps, beside, strict=True)
    ]


def _lateness(seconds: float, neighbours: str) -> str:
    if abs(seconds) < 0.05:
        return "on time"
    side = "later" if seconds > 0 else "earlier"
    return f"{abs(seconds):.1f} s {side} than {neighbours}"
