"""The detections arranged by sensor, and the kinematic travel time every stage predicts from."""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.features import SensorFeatures
from roadlink.association.associators.assignment.params import (
    PRIOR_TEST_SAMPLE,
    SPARSE_SHARE,
    AssignmentParams,
)
from roadlink.association.associators.assignment.robust import median
from roadlink.association.detections import Detections, FloatArray, IntArray

if TYPE_CHECKING:
    from roadlink.association.associators.assignment.clock_drift import ClockDrift
    from roadlink.association.associators.assignment.clock_steps import ClockStep

ComplexArray = npt.NDArray[np.complex128]
BoolArray = npt.NDArray[np.bool_]

# The share of a travel time predicted from the far end's speed, before a segment learns its own:
# both ends' speeds weigh alike.
KINEMATIC_SKEW = 0.5
# Times are stamped in steps where each lies within this share of a step of a whole number of
# steps from its sensor's first time.
STEP_TOLERANCE = 1e-3
# The spreading of stamped times over their step (`Sensors.within_step`) draws from this seed:
# the same batch gets the same times, run after run.
SPREAD_SEED = 0


def travel_time(
    length: FloatArray | float,
    speed_a: FloatArray | float,
    speed_b: FloatArray | float,
    skew: FloatArray | float = KINEMATIC_SKEW,
) -> FloatArray:
    """Travel time over `length` from a detection at speed_a to one at speed_b: a share
    `1 - skew` of the way at the first speed, `skew` at the second (the kinematic prediction
    at KINEMATIC_SKEW). Arrays in, arrays out; numbers in, a number out."""
    return np.multiply(length, (1.0 - skew) / speed_a + skew / speed_b)


@dataclass
class Sensors:
    """Detections arranged by sensor in road order, times ascending within a sensor."""

    positions: FloatArray  # distinct positions, ascending
    order: IntArray  # detection indices sorted by (sensor, time)
    start: IntArray  # order[start[k]:start[k+1]] are sensor k's detections
    sensor: IntArray  # sensor index of every detection
    time: FloatArray
    speed: FloatArray  # floored
    log_speed: FloatArray
    relative_speed: FloatArray  # log speed minus the median log speed at its sensor
    # The same, in `order` (so a sensor's values are one contiguous slice)
    sorted_time: FloatArray
    sorted_inverse_speed: FloatArray
    sorted_log_speed: FloatArray
    top_speed: FloatArray  # the fastest speed measured at each sensor
    median_speed: FloatArray  # the median (floored) speed at each sensor
    features: SensorFeatures | None = None  # lane, length, class, where detectors report them
    clock_offsets: FloatArray | None = None  # seconds taken from each sensor's times (`clocks`)
    speed_floor: float = 0.0  # what `speed` is floored at: a speed there was read lower
    swapped: tuple[int, ...] = ()  # each k whose sensors k, k + 1 were exchanged (`sensor_order`)
    clock_steps: tuple[ClockStep, ...] = ()  # clocks that stepped while reporting (`clock_steps`)
    clock_drifts: tuple[ClockDrift, ...] = ()  # clocks that drifted while reporting (`clock_drift`)
    _reaching: dict[int, tuple[IntArray, IntArray]] = field(default_factory=dict, repr=False)
    _starts: list[int] = field(default_factory=list, repr=False)  # `start` as Python ints

    def members(self, k: int) -> IntArray:
        # Sliced by Python ints: a paper-size batch asks a hundred times, and numpy's integers
        # cost more to slice by than the slice itself.
        starts = self._starts or self._python_starts()
        return self.order[starts[k] : starts[k + 1]]

    def _python_starts(self) -> list[int]:
        self._starts.extend(self.start.tolist())
        return self._starts

    @cached_property
    def first_time(self) -> FloatArray:
        """Each sensor's first detection time: where the batch's window opens for it."""
        return self.sorted_time[self.start[:-1]]

    @cached_property
    def sparse(self) -> BoolArray:
        """The sensors that saw fewer than PRIOR_TEST_SAMPLE detections and under SPARSE_SHARE
        of what a neighbour saw, that neighbour at least PRIOR_TEST_SAMPLE: in a busy batch, a
        sensor that stopped reporting early (or started late). Its few detections tell the
        traffic of a minute, not of the batch, and its segments' links are few and all near the
        window's edge."""
        seen = np.diff(self.start)
        neighbour = np.maximum(np.r_[0, seen[:-1]], np.r_[seen[1:], 0])
        result: BoolArray = (
            (seen < PRIOR_TEST_SAMPLE)
            & (seen < SPARSE_SHARE * neighbour)
            & (neighbour >= PRIOR_TEST_SAMPLE)
        )
        return result

    @cached_property
    def typical_speed(self) -> FloatArray:
        """Each sensor's typical speed, for the prior's kinematic travel times: its median, but a
        sparse sensor's is its neighbours', interpolated by position. Its few detections tell the
        speeds of a minute, not of the batch, and a link over it is priced by the travel times
        that add up through it: with its median from its first ten vehicles (12 % fast, SUMO's
        dense traffic) the links over it expected a travel time 6 % short, eight spreads of a
        segment's, and 95 % of them were wrong."""
        sparse = self.sparse
        if not sparse.any():
            return self.median_speed
        typical = self.median_speed.copy()
        busy = ~sparse
        typical[sparse] = np.interp(self.positions[sparse], self.positions[busy], typical[busy])
        return typical

    @cached_property
    def reads_one_speed(self) -> BoolArray:
        """Per sensor: whether it reports one speed, above the floor, for each of its vehicles
        (ONE_SPEED_DETECTIONS or more; a loop that counts vehicles and fills in a default, a
        stuck reading). Its speeds tell the vehicles nothing apart, nor its calibration."""
        if self.order.size == 0:
            return np.zeros(self.positions.size, dtype=bool)
        lowest = np.minimum.reduceat(self.speed[self.order], self.start[:-1])
        one: BoolArray = (np.diff(self.start) >= ONE_SPEED_DETECTIONS) & (lowest == self.top_speed)
        return one & (self.top_speed > self.speed_floor)

    @property
    def calibration_speed(self) -> FloatArray:
        """Each sensor's typical speed where it tells its calibration; NaN where it reads one
        speed (`reads_one_speed`)."""
        return np.where(self.reads_one_speed, np.nan, self.typical_speed)

    @property
    def stepped_sensors(self) -> frozenset[int]:
        """The sensors whose clocks stepped while they reported (`clock_steps`)."""
        return frozenset(step.sensor for step in self.clock_steps)

    @cached_property
    def silent_gaps(self) -> BoolArray:
        """Per place in `order`: whether its sensor was silent since its report before
        (`silences.silent_gaps`)."""
        from roadlink.association.associators.assignment.silences import silent_gaps

        return silent_gaps(self)

    @cached_property
    def slowest_speed(self) -> FloatArray:
        """The slowest (floored) speed measured at each sensor."""
        result: FloatArray = np.minimum.reduceat(self.speed[self.order], self.start[:-1])
        return result

    @cached_property
    def last_time(self) -> FloatArray:
        """Each sensor's last detection time: where the batch's window closes for it."""
        return self.sorted_time[self.start[1:] - 1]

    @cached_property
    def arrival_keys(self) -> ComplexArray | None:
        """Every detection as sensor + i time, in `order`: sorted as numpy sorts complex numbers
        (by real part, then imaginary), so one `searchsorted` finds a time among one sensor's
        arrivals (`gating._arrivals_between`). None where a time is NaN (numpy sorts a complex
        number with a NaN part after all others, whatever its sensor)."""
        if np.isnan(self.sorted_time).any():
            return None
        keys = np.empty(self.time.size, dtype=np.complex128)
        keys.real = self.sensor[self.order]
        keys.imag = self.sorted_time
        return keys

    def reaching(self, reach: int) -> tuple[IntArray, IntArray]:
        """Every detection with each of the `reach` sensors after it (those there are), by that
        sensor, then by detection as in `order`: the detections, and the sensors. Worked out
        once a batch: every pass that gates all the links at once (`gating.EverySensor`) asks."""
        if reach not in self._reaching:
            # Sensor q's departures are one run of `order`: the sensors q - reach to q - 1.
            q = np.arange(1, self.positions.size)
            lo = self.start[np.maximum(q - reach, 0)]
            count = self.start[1:-1] - lo
            at = np.repeat(lo - (np.cumsum(count) - count), count)
            at += np.arange(at.size)
            self._reaching[reach] = self.order[at], np.repeat(q, count)
        return self._reaching[reach]

    def by_track(self, detections: IntArray, track: IntArray) -> IntArray:
        """The detections (each in a track) sorted by track, then sensor: the order of
        np.lexsort((sensor, track)), from one sort of a combined key (a third of its time). A
        track holds at most one detection per sensor, so no two keys are equal, and a stable
        sort (timsort, quicker on the runs of a track's detections) gives the same order."""
        key = track[detections] * self.positions.size + self.sensor[detections]
        return detections[key.argsort(kind="stable")]

    @cached_property
    def time_step(self) -> float:
        """The step the times are stamped in (a whole second, a tenth), or 0 where they fall on
        none: the smallest gap between a sensor's distinct times, where every time lies a whole
        number of it from its sensor's first (a sensor's clock set right moves them all)."""
        gaps = np.diff(self.sorted_time)
        gaps[self.start[1:-1] - 1] = 0.0  # from one sensor's last time to the next one's first
        positive = gaps[gaps > 0]
        if positive.size == 0:
            return 0.0
        step = float(positive.min())
        first = np.repeat(self.first_time, np.diff(self.start))
        steps = (self.sorted_time - first) / step
        off = np.abs(steps - np.rint(steps))
        return step if bool((off[np.isfinite(off)] <= STEP_TOLERANCE).all()) else 0.0

    def within_step(self, share: float) -> Sensors:
        """These detections with every time moved by a uniform draw within its stamp's step
        (`time_step`), and sorted again, where that step is at least `share` of the shortest
        segment's typical travel time; else these detections as they are. A stamped time says
        only that the passage fell within its step: a histogram of travel times (the prior's)
        built from whole steps is a comb, whose teeth stand out as biases (SUMO's irregular
        road, sensors 30 to 700 m apart, stamped in whole seconds: a travel time 0.41 of the
        kinematic one on a segment of 60 m, 2.3 s)."""
        step = self.time_step
        if step == 0.0 or self.positions.size < 2:
            return self
        speeds = self.median_speed
        shortest = travel_time(np.diff(self.positions), speeds[:-1], speeds[1:]).min()
        if step < share * shortest:
            return self
        draws = np.random.default_rng(SPREAD_SEED).uniform(-step / 2, step / 2, self.time.size)
        time = self.time.copy()
        time[self.order] += draws  # by place in `order`: the same whatever the input's order
        order = np.lexsort((time, self.sensor)).astype(np.int64)
        return replace(
            self,
            order=order,
            time=time,
            sorted_time=time[order],
            sorted_inverse_speed=1.0 / self.speed[order],
            sorted_log_speed=self.log_speed[order],
            _reaching={},
            _starts=[],
        )

    def typical_travel_time(self) -> float | None:
        """The median kinematic travel time between neighbouring sensors at their median speeds
        (None with one sensor)."""
        if self.positions.size < 2:
            return None
        speeds = self.median_speed
        gaps = self.positions[1:] - self.positions[:-1]  # np.diff
        return median(travel_time(gaps, speeds[:-1], speeds[1:]))


def arrival_keys_of(sensor: IntArray, time: FloatArray) -> ComplexArray:
    """`Sensors.arrival_keys` of these times at these sensors: where `searchsorted` among the
    arrivals finds them."""
    keys = np.empty(sensor.size, dtype=np.complex128)
    keys.real = sensor
    keys.imag = time
    return keys


def arrange(detections: Detections, params: AssignmentParams) -> Sensors:
    """Index the detections by sensor and time, with speeds floored (never divide by ~0)."""
    positions, sensor = np.unique(detections.position, return_inverse=True)
    sensor = sensor.astype(np.int64)
    order, start = _by_sensor_and_time(
        detections.timestamp, detections.velocity, sensor, positions.size
    )
    floor = params.velocity_floor * float(median(detections.velocity))
    speed = np.maximum(detections.velocity, floor)
    # Where two sensors' positions are swapped, their detections are taken the other way
    # round; where a sensor's clock is off, its times are set right: the tracks are built on
    # them. (Both measure lags against this module's `travel_time`, hence imported here.)
    from roadlink.association.associators.assignment.clock_drift import clock_drifts
    from roadlink.association.associators.assignment.clock_steps import clock_steps
    from roadlink.association.associators.assignment.clocks import clock_offsets
    from roadlink.association.associators.assignment.sensor_order import (
        in_road_order,
        swapped_pairs,
    )

    time = detections.timestamp
    swapped, lags = swapped_pairs(
        positions,
        _per_sensor(time, order, start),
        _per_sensor(speed, order, start),
    )
    if swapped:  # the lags measured were those of the sensors as reported
        sensor = in_road_order(sensor, swapped)
        order, start = _by_sensor_and_time(
            detections.timestamp, detections.velocity, sensor, positions.size
        )
        lags = None
    offsets = clock_offsets(positions, time[order], speed[order], start, lags)
    if offsets.any():
        time = time - offsets[sensor]
    steps = clock_steps(
        positions,
        _per_sensor(time, order, start),
        _per_sensor(speed, order, start),
        offsets,
    )
    if steps:
        time = time.copy()
        for step in steps:
            stepped = order[start[step.sensor] : start[step.sensor + 1]]
            time[stepped] -= step.before
            time[stepped[step.later]] -= step.after - step.before
        order, start = _by_sensor_and_time(time, detections.velocity, sensor, positions.size)
    drifts = clock_drifts(
        positions,
        _per_sensor(time, order, start),
        _per_sensor(speed, order, start),
    )
    if drifts:
        time = time.copy()
        for drift in drifts:
            drifted = order[start[drift.sensor] : start[drift.sensor + 1]]
            time[drifted] -= drift.at(time[drifted])
        order, start = _by_sensor_and_time(time, detections.velocity, sensor, positions.size)
    log_speed = np.log(speed)
    typical = np.array(
        [median(log_speed[order[start[k] : start[k + 1]]]) for k in range(positions.size)]
    )
    return Sensors(
        positions,
        order,
        start,
        sensor,
        time,
        speed,
        log_speed,
        log_speed - typical[sensor],
        time[order],
        1.0 / speed[order],
        log_speed[order],
        np.maximum.reduceat(speed[order], start[:-1]) if order.size else np.zeros(0),
        np.array([median(speed[order[start[k] : start[k + 1]]]) for k in range(positions.size)]),
        SensorFeatures.of(detections),
        offsets,
        floor,
        tuple(swapped),
        tuple(steps),
        tuple(drifts),
    )


def _per_sensor(values: FloatArray, order: IntArray, start: IntArray) -> list[FloatArray]:
    """Each sensor's `values`, in the order `order` gives (`start`: where each sensor's run
    begins), as the clocks' searches read them."""
    return [values[order[start[k] : start[k + 1]]] for k in range(start.size - 1)]


def _by_sensor_and_time(
    time: FloatArray, velocity: FloatArray, sensor: IntArray, n_sensors: int
) -> tuple[IntArray, IntArray]:
    """The detections' order by sensor, then time, and where each sensor's run starts. Ties
    broken by speed, then input order, so a shuffled input gives the same grouping."""
    order = np.lexsort((velocity, time, sensor)).astype(np.int64)
    start = np.searchsorted(sensor[order], np.arange(n_sensors + 1)).astype(np.int64)
    return order, start


# A sensor with at least this many detections that all report one speed is named.
ONE_SPEED_DETECTIONS = 20


def one_speed_warnings(s: Sensors) -> list[str]:
    """A sentence for each sensor that reports one speed for every vehicle (a loop that counts
    vehicles and fills in a default speed, a stuck reading): its speeds tell the vehicles
    nothing apart, and whoever keeps it should know. The association learns that from the
    tracks as it learns any sensor's speed spread."""
    # (All floored is a standing queue read below the floor, not one reading.)
    return [
        f"the sensor at position {s.positions[k]:g} reports one speed ({s.top_speed[k]:g}) "
        "for every vehicle: its speeds tell vehicles nothing apart (a loop that counts "
        "and fills in a default, or a stuck reading?)"
        for k in np.flatnonzero(s.reads_one_speed).tolist()
    ]
