"""Sensors' clocks that drift while they report, followed over the batch and set right before
anything is linked.

`clocks` takes one offset a sensor and `clock_steps` one jump. A clock that runs fast or slow
drifts: a crystal 0.01 % off gains nine seconds a day, and a detector whose time server
corrects it now and then drifts and steps in turn. Whatever single offset or step is taken,
part of the batch is left seconds off (SUMO's dense motorway without lane and length, the
middle sensor's clock drifting to 10 s late over the batch, five seeds: 74.0 % of the
detections right, 91.8 % on time).

So, once the clocks are set right as a whole and at their steps, each sensor where traffic flows
at it and its neighbours is followed over the batch (an end sensor, which has one neighbour,
where it flows at the next two sensors: `_followable`). A sample of its detections, away from
the batch's edges, is scored at every offset of a grid by how well each detection then fits
its neighbours: its best pair at each neighbouring sensor where its own speed says it would be,
as `clock_steps` scores a step (`misfit_grid`). The clock's offset over the batch is the path
through the grid, detection after detection in time order, whose misfits plus a price for every
bin it moves are least, moving one way only but for jumps, which cost a price of their own
(`least_paths`, a Viterbi over the grid): a clock that runs fast keeps gaining until it is set
right, and a path free to turn back at every detection would follow the comb of dense
traffic's neighbouring vehicles. It is taken where it fits clearly better than any single
offset (DRIFT_SAVING a sampled detection, half of it a segment: `_least_saving`), each of the
sensor's segments better than as reported (a neighbour's drift moves one segment; the sensor's
own, both), and moves by CLOCK_LEAST_BINS or more; each detection is then set right by the
path's offset at its time, carried on at the path's slope beyond the sample. The clearest
first, the others followed again on the times it set right.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.clock_steps import (
    STEP_FIT_BINS,
    bin_width,
    neighbouring_sensors,
    pair_cost,
    speed_change,
)
from roadlink.association.associators.assignment.clocks import (
    CLOCK_CONFIRM_GATE,
    CLOCK_CONFIRM_SAVING,
    CLOCK_LEAST_BINS,
    CLOCK_LEAST_DETECTIONS,
    CLOCK_SAMPLE,
    Road,
    neighbours_of,
)
from roadlink.association.associators.assignment.params import FLOWING_SHARE
from roadlink.association.detections import FloatArray, IntArray

# The offsets searched either side of the times as set right so far: this many of the lags'
# bins (a bin is 5 % of a travel time: one and a half travel times).
DRIFT_REACH_BINS = 30
# The grid's step, in bins.
DRIFT_GRID_STEP = 0.5
# What the path pays for moving by one bin: half of what leaving a detection alone at its two
# neighbours costs, so that no handful of detections pulls it off, and a drift of twenty bins
# pays for itself over a few dozen.
DRIFT_MOVE_COST = 0.5 * CLOCK_CONFIRM_GATE
# What the path pays for a jump, either way and by any distance (a clock set right by its time
# server now and then, or stepping, between stretches of drift): what leaving two sampled
# detections alone at both neighbours costs, so that the detections either side must fit the
# jump clearly better, and a path that turned back at every vehicle of dense traffic's comb
# could not pay for it. Measured, on the exported on-time cases below the largest saving rose
# from 0.79 to 0.92 a detection; at three times the gate the faults gained less.
DRIFT_JUMP_COST = 2.0 * CLOCK_CONFIRM_GATE
# The least share of the sampled detections between two jumps, or before the first or after
# the last (SUMO's dense motorway, the first sensor drifting: a jump after its first 5 sampled
# detections of 83, which fitted the neighbours' comb 5 s off, took it from 99.8 to 97.3 %).
DRIFT_LEAST_STRETCH = 0.1
# What the path must save against the best single offset, a sampled detection (twice what
# `clocks` asks of a small offset). On 350 exported on-time SUMO cases (the main, validation,
# speed-noise and fault groups, with lane and length and without) no sensor's path saves more
# than 0.79 (dense traffic whose speeds are read with an 8 % error: the misfits' speed term
# expects 5 %), 0.92 since paths may jump (315 cases; dense traffic at a 6 % error); a clock
# drifting 10 s over the batch saves 1.5-5.9.
DRIFT_SAVING = 2.0 * CLOCK_CONFIRM_SAVING


@dataclass(frozen=True)
class ClockDrift:
    """Sensor `sensor`'s clock, once set right as a whole and at any step, was still
    `offset[i]` seconds late about its report stamped `time[i]` (ascending; linear between)."""

    sensor: int
    time: FloatArray = field(repr=False)
    offset: FloatArray = field(repr=False)
    # Each i where the clock jumped between its reports time[i] and time[i + 1].
    jumps: IntArray = field(default_factory=lambda: np.zeros(0, dtype=np.int64), repr=False)

    def at(self, times: FloatArray) -> FloatArray:
        """The offset (s) at each of `times`: the path's between its first and last sample;
        before and after them, carried on at the slope of its outer fifth, or of the stretch
        beyond its outermost jump where that is shorter (the sample keeps away from the batch's
        edges, and a clock that drifts drifts on)."""
        offset = np.interp(times, self.time, self.offset)
        last = self.time.size - 1
        outer = max(1, self.time.size // 5)
        first_run = int(self.jumps[0]) if self.jumps.size else last
        last_run = int(self.jumps[-1]) + 1 if self.jumps.size else 0
        for end, inner, side in (
            (0, min(outer, first_run), -1.0),
            (last, max(last - outer, last_run), 1.0),
        ):
            span = float(self.time[end] - self.time[inner])
            slope = float(self.offset[end] - self.offset[inner]) / span if span else 0.0
            beyond = side * (times - self.time[end]) > 0
            offset[beyond] = self.offset[end] + slope * (times[beyond] - self.time[end])
        return offset


def clock_drifts(
    positions: FloatArray, times: list[FloatArray], speeds: list[FloatArray]
) -> list[ClockDrift]:
    """The sensors whose clocks drift over the batch, each sensor's detection times (ascending,
    set right as a whole and at their steps) and speeds given in road order; the clearest
    first, its neighbours followed again on the times it set right."""
    n = positions.size
    if n < 3:
        return []
    typical = np.array([np.median(v) if v.size else 0.0 for v in speeds])
    flowing = typical >= FLOWING_SHARE * typical.max()
    times, speeds = list(times), list(speeds)
    followed = [k for k in range(n) if _followable(k, flowing, times)]
    drifts: list[ClockDrift] = []
    while followed:
        found = _drifts(Road(positions, times, speeds), followed)
        if not found:
            break
        drift, _ = max(found, key=lambda item: item[1])
        drifts.append(drift)
        k = drift.sensor
        set_right = times[k] - drift.at(times[k])
        # A clock set back jumps: its detections' order may change.
        order = np.argsort(set_right, kind="stable")
        times[k], speeds[k] = set_right[order], speeds[k][order]
        followed.remove(drift.sensor)
    return drifts


def _followable(k: int, flowing: npt.NDArray[np.bool_], times: list[FloatArray]) -> bool:
    """Whether sensor k's clock can be followed: traffic flows at it and its neighbours, each
    with enough detections. An end sensor has one segment, whose drifting travel times may be
    its neighbour's clock as well as its own: it is followed where that neighbour could be too
    (traffic flows at the next sensor on), and a neighbour's drift moves both the neighbour's
    segments, which the neighbour's own path then fits better (the clearest first)."""
    first = min(max(k - 1, 0), flowing.size - 3)  # the three sensors round k, on the road
    return all(
        flowing[j] and times[j].size >= CLOCK_LEAST_DETECTIONS for j in range(first, first + 3)
    )


@dataclass(frozen=True)
class _Followed:
    """A sensor's sampled detections (places in time order), the offsets of its grid, each
    sampled detection's misfit at each neighbour and each offset ([detection, offset]) and
    summed over its neighbours (`misfit`), and what its path must save (`_least_saving`)."""

    sensor: int
    sample: IntArray
    grid: FloatArray
    width: float
    sides: list[FloatArray]
    misfit: FloatArray
    saving: float


def _drifts(road: Road, followed: list[int]) -> list[tuple[ClockDrift, float]]:
    """The drifts of the `followed` sensors whose paths stand out (see the module's docstring),
    each with what it saves against the sensor's times as they are; every sensor's path found
    at once (`least_paths`)."""
    candidates = [one for k in followed if (one := _followed(road, k)) is not None]
    if not candidates:
        return []
    move = DRIFT_MOVE_COST * DRIFT_GRID_STEP
    paths, totals, jumps = least_paths([one.misfit for one in candidates], move, DRIFT_JUMP_COST)
    # A stretch between jumps (or before the first, after the last) of a few detections is
    # where they fit dense traffic's comb by chance: such a sensor's path jumps not at all.
    short = [
        c
        for c, (one, jumped) in enumerate(zip(candidates, jumps, strict=True))
        if np.diff(np.r_[0, jumped + 1, one.sample.size]).min()
        < DRIFT_LEAST_STRETCH * one.sample.size
    ]
    if short:
        again = least_paths([candidates[c].misfit for c in short], move)
        for c, path, total, jumped in zip(short, *again, strict=True):
            paths[c], totals[c], jumps[c] = path, total, jumped
    drifts = []
    for one, path, total, jumped in zip(candidates, paths, totals, jumps, strict=True):
        drift = _drift(road, one, path, total, jumped)
        if drift is not None:
            drifts.append(drift)
    return drifts


def _followed(road: Road, k: int) -> _Followed | None:
    """Sensor k's sample and misfits on the grid; None where no path could stand out: each
    detection at its own best offset, with nothing paid for moving, saves too little against
    the best single offset."""
    width = bin_width(road.positions, road.speeds, k)
    sample = _sample(road, k, width)
    if sample.size < CLOCK_LEAST_DETECTIONS:
        return None
    saving = _least_saving(road, k, sample.size)
    # No path saves more than the misfits at the times as they are (a single offset): where
    # they are small already (the paper's traffic on time: 0.7-0.8 a detection), the grid is
    # not worked out.
    as_is = misfit_grid(road, k, np.array([0.0, width]), width, sample)
    if sum(float(side[:, 0].sum()) for side in as_is) < saving:
        return None
    steps = DRIFT_REACH_BINS / DRIFT_GRID_STEP
    grid = width * DRIFT_GRID_STEP * np.arange(-steps, steps + 1)
    sides = misfit_grid(road, k, grid, width, sample)
    misfit = np.sum(sides, axis=0)
    if misfit.min(axis=1).sum() > misfit.sum(axis=0).min() - saving:
        return None
    return _Followed(k, sample, grid, width, sides, misfit, saving)


def _least_saving(road: Road, k: int, sampled: int) -> float:
    """What sensor k's path must save against its best single offset: DRIFT_SAVING a sampled
    detection, half of it a segment. An end sensor's one segment saves half what a sensor
    between two saves for the same drift (0.3-1.05 a detection, against 1.5-5.9, SUMO's dense
    motorway with the first sensor drifting 10 s over the batch), and no end sensor of the
    on-time cases saves more than 0.41 (the middle's: 0.79)."""
    segments = len(neighbouring_sensors(k, road.positions.size))
    return DRIFT_SAVING * sampled * segments / 2


def _drift(
    road: Road, one: _Followed, path: IntArray, total: float, jumps: IntArray
) -> tuple[ClockDrift, float] | None:
    """The drift `path` follows (with its `total` cost and its `jumps`), and what it saves
    against the times as they are, where it stands out."""
    misfit, sample, sides, saving = one.misfit, one.sample, one.sides, one.saving
    offset = one.grid[path]
    if offset.max() - offset.min() < CLOCK_LEAST_BINS * one.width:
        return None
    if total > float(misfit.sum(axis=0).min()) - saving:
        return None
    on_time = int(np.argmin(np.abs(one.grid)))
    taken = np.arange(sample.size), path
    if any(side[taken].sum() > side[:, on_time].sum() - 0.5 * saving for side in sides):
        return None
    as_is = float(misfit[:, on_time].sum())
    drift = ClockDrift(one.sensor, road.times[one.sensor][sample], offset, jumps)
    return drift, as_is - total


def _sample(road: Road, k: int, width: float) -> IntArray:
    """Up to CLOCK_SAMPLE of sensor k's detections (places in time order), evenly spread, each
    far enough inside the batch that its neighbours' detections lie in it at any offset of the
    grid."""
    time, speed = road.times[k], float(np.median(road.speeds[k]))
    travel = max(
        abs(float(road.positions[j] - road.positions[k]))
        for j in neighbouring_sensors(k, road.positions.size)
    )
    edge = travel / speed + DRIFT_REACH_BINS * width
    first = min(float(t[0]) for t in road.times if t.size)
    last = max(float(t[-1]) for t in road.times if t.size)
    inner = np.flatnonzero((time > first + edge) & (time < last - edge))
    picked = np.linspace(0, inner.size - 1, min(inner.size, CLOCK_SAMPLE)).astype(np.int64)
    return inner[np.unique(picked)]


def misfit_grid(
    road: Road, k: int, offsets: FloatArray, width: float, sample: IntArray
) -> list[FloatArray]:
    """For each neighbour of sensor k, the misfit of each of its detections `sample` (places
    in time order) at each of `offsets` (ascending, evenly spaced), [detection, offset]: the
    least cost of a pair with the neighbour's detections where its own speed says it would be,
    as `clock_steps` costs one at one offset, at most half of CLOCK_CONFIRM_GATE (what leaving
    it alone costs). Each pair is found once over the span of offsets and costed at those that
    bring it within STEP_FIT_BINS bins."""
    step = float(offsets[1] - offsets[0])
    reach = STEP_FIT_BINS * width
    time, speed = road.times[k][sample], road.speeds[k][sample]
    sides = []
    for j in neighbouring_sensors(k, road.positions.size):
        expected = time + (road.positions[j] - road.positions[k]) / speed
        lo = np.searchsorted(road.times[j], expected - offsets[-1] - reach)
        count = np.searchsorted(road.times[j], expected - offsets[0] + reach) - lo
        which = np.repeat(np.arange(time.size), count)
        at = np.arange(which.size) + np.repeat(lo - (np.cumsum(count) - count), count)
        # With the sensor's clock d seconds late, a pair's time error is error + d.
        error = road.times[j][at] - expected[which]
        change = speed_change(road, k, j, sample[which], at)
        first = np.maximum(np.ceil((-error - reach - offsets[0]) / step).astype(np.int64), 0)
        last = np.minimum(
            np.floor((-error + reach - offsets[0]) / step).astype(np.int64), offsets.size - 1
        )
        columns = np.maximum(last - first + 1, 0)
        pair = np.repeat(np.arange(which.size), columns)
        column = np.arange(pair.size) + np.repeat(first - (np.cumsum(columns) - columns), columns)
        cost = pair_cost(error[pair] + offsets[column], change[pair], width)
        least = np.full((sample.size, offsets.size), 0.5 * CLOCK_CONFIRM_GATE)
        np.minimum.at(least, (which[pair], column), cost)
        sides.append(least)
    return sides


def least_paths(
    costs: list[FloatArray], move: float, jump: float = np.inf
) -> tuple[list[IntArray], list[float], list[IntArray]]:
    """For each of `costs` ([step, state], as many states each), the path through it whose
    costs plus `move` per state moved, and `jump` per jump, are least, where it moves only up or
    only down except by jumps, which go anywhere: each step's state, the path's total, and each
    step i after which it jumps.

    A Viterbi over every cost at once (each padded to the most steps with steps of no cost,
    where a path stays for nothing), falling paths as rising ones through the states reversed.
    With the price linear in the distance, the least arrival at state s from below is a running
    minimum of best[j] - move * j over j <= s, plus move * s; a jump arrives from the least
    state of all; the path is read back from the stored bests."""
    steps = max(cost.shape[0] for cost in costs)
    states = costs[0].shape[1]
    stacked = np.zeros((2 * len(costs), steps, states))
    for c, cost in enumerate(costs):
        stacked[2 * c, : cost.shape[0]] = cost
        stacked[2 * c + 1, : cost.shape[0]] = cost[:, ::-1]
    ramp = move * np.arange(states)
    best = np.empty_like(stacked)
    best[:, 0] = stacked[:, 0]
    for i in range(1, steps):
        arrival = np.minimum.accumulate(best[:, i - 1] - ramp, axis=1)
        np.add(arrival, ramp, out=arrival)
        np.minimum(arrival, best[:, i - 1].min(axis=1, keepdims=True) + jump, out=arrival)
        np.add(arrival, stacked[:, i], out=best[:, i])
    rows = np.arange(stacked.shape[0])
    path = np.empty((stacked.shape[0], steps), dtype=np.int64)
    jumped_to = np.zeros((stacked.shape[0], steps), dtype=bool)
    path[:, -1] = np.argmin(best[:, -1], axis=1)
    above = np.arange(states)[None, :]
    for i in range(steps - 1, 0, -1):
        # The predecessor: the least of best[j] - move * j over j at or below the state, or
        # the least state of all where a jump from it arrives cheaper.
        lowered = best[:, i - 1] - ramp
        lowered[above > path[:, i][:, None]] = np.inf
        below = np.argmin(lowered, axis=1)
        crawled = lowered[rows, below] + ramp[path[:, i]]
        anywhere = np.argmin(best[:, i - 1], axis=1)
        jumped_to[:, i] = best[rows, i - 1, anywhere] + jump < crawled
        path[:, i - 1] = np.where(jumped_to[:, i], anywhere, below)
    totals = best[rows, -1, path[:, -1]]
    paths, chosen_totals, jumps = [], [], []
    for c, cost in enumerate(costs):
        way = int(np.argmin(totals[2 * c : 2 * c + 2]))
        found = path[2 * c + way, : cost.shape[0]]
        paths.append(found if way == 0 else states - 1 - found)
        chosen_totals.append(float(totals[2 * c + way]))
        jumps.append(np.flatnonzero(jumped_to[2 * c + way, 1 : cost.shape[0]]))
    return paths, chosen_totals, jumps


def drift_warnings(positions: FloatArray, drifts: list[ClockDrift]) -> list[str]:
    """A sentence for each sensor whose clock drifted, for whoever keeps the detector's clock."""
    n = positions.size
    return [
        f"the sensor at position {positions[drift.sensor]:g} stamps its detections "
        f"{_lateness(float(drift.offset[0]))} than {neighbours_of(drift.sensor, n)} about "
        f"its report stamped {drift.time[0]:g}, and {_lateness(float(drift.offset[-1]))} "
        f"about its report stamped {drift.time[-1]:g}: its clock drifts{_jumps(drift)}; its "
        "times were set right for the association"
        for drift in drifts
    ]


def _jumps(drift: ClockDrift) -> str:
    """How often the clock jumped (set right by its time server, or stepping) and when first;
    nothing where it drifted alone."""
    count = drift.jumps.size
    if not count:
        return ""
    first = float(drift.time[drift.jumps[0] + 1])
    return f" and jumps ({count} {'time' if count == 1 else 'times'}, first about {first:g})"


def _lateness(seconds: float) -> str:
    if abs(seconds) < 0.05:
        return "no later or earlier"
    return f"{abs(seconds):.1f} s {'later' if seconds > 0 else 'earlier'}"
