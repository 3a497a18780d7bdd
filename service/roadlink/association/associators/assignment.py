"""`assignment`: track building by sparse minimum-cost assignment, sensor after sensor.

The paper clusters detections as independent points. They are not: a target passes each sensor
once, in position order, and its speed changes little between neighbouring sensors. This
associator uses that structure:

1. Sensors are visited in road order. At each sensor the open tracks (whose last detection lies at
   one of the previous `max_skip + 1` sensors, so a missed detection is bridged) are matched
   one-to-one to the sensor's detections by minimum-cost bipartite assignment. The cost of a link
   from detection a to detection b is a kinematic negative log-likelihood: the travel time
   predicted from both ends' speeds, `dx * (1/v_a + 1/v_b) / 2`, scaled by the segment's learned
   bias and skewed towards one end where the segment's own links say so, against the observed
   one; plus penalties on the speed change and on a speed far from
   the track's own pace (each residual costs -2 log of its learned, heavy-tailed density); plus
   a penalty for each sensor skipped. A detection left unmatched starts a track (a birth), a
   track left unmatched waits (a miss); links costlier than `gate_cost` are never made.
2. Candidate pairs are gated in time (sorted times and `searchsorted`), so the work grows with the
   number of detections, not its square, and each sensor's assignment is solved by the sparse
   LAPJVsp algorithm with dummy birth / miss nodes.
3. A fixed kinematic model breaks in congestion, so each segment's behaviour (travel-time bias,
   skew and spread, speed ratio and its spread) is learned robustly (median, MAD) from the links
   of the confident tracks, and the detections are re-associated with it: a few EM-style
   rounds. Each round also measures how heavy the residuals' tails are (`Tails`): in real
   traffic a few per cent of the links lie 5 to 20 core spreads off, and a Gaussian cost would
   break them.
4. The sequential pass chooses each link knowing only the past, so the tracks are then re-paired
   with hindsight: at every sensor boundary, track prefixes are matched to track suffixes again,
   each seen whole (`refine_boundaries`).
5. Faults: duplicated reports (the same passage reported twice) never start a track of their own;
   tracks shorter than `min_track_length`, or whose links save too little over leaving their
   detections apart, are false alarms (-1), unless the batch's time window cut them (a vehicle
   that passed the first sensor in the batch's last seconds is seen once, and is a target).
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import ClassVar

import numpy as np
import numpy.typing as npt
from pydantic import Field
from scipy.optimize import linear_sum_assignment
from scipy.sparse import coo_matrix, csr_matrix
from scipy.sparse.csgraph import connected_components, min_weight_full_bipartite_matching

from roadlink.association.associators.base import Associator, AssociatorParams, Progress
from roadlink.association.detections import Detections, FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]

MIN_RELATIVE_SPREAD = 0.01
REFINE_GATE_FACTOR = 2.0
# A link's mean speed may exceed the fastest speed measured at its sensors by this factor at most.
FASTEST_SHARE = 1.5
# The prior's search for each segment's bias: travel times up to 10x off the kinematic guess,
# in bins of 5 %, from a sample of this many detections per sensor.
PRIOR_LOG_RANGE = float(np.log(10.0))
PRIOR_BIN = 0.05
PRIOR_SAMPLE = 400
# That search also looks at the pairs alone whose relative speeds differ by at most this share of
# the spread of relative speeds at a sensor.
PRIOR_AGREEMENT = 0.5
# A pile-up of pairs away from the kinematic prediction is believed only when it holds this many
# standard deviations (Poisson) more pairs than the kinematic prediction's own bin.
PRIOR_SIGNIFICANCE = 5.0
# Fewer sampled detections than this cannot reach that significance (a handful of targets): their
# mode is taken as it is, as long as it stands above the background at all.
PRIOR_TEST_SAMPLE = 40
# Heavy tails of the residuals (see Tails): learned from the confident tracks' links, starting
# from this prior.
PRIOR_TAILS = (0.01, 3.0)
TAIL_MIN_SAMPLES = 30
TAIL_SAMPLE = 5000
TAIL_EM_ITERATIONS = 50
TAIL_WEIGHT_RANGE = (0.001, 0.5)
TAIL_MIN_SCALE = 2.0
TAIL_MAX_SCALE = 30.0
MATCH_BATCH = 2000  # edges per sparse assignment: small enough to stay linear, few enough calls
COST_QUANTUM_INVERSE = 1024.0  # sparse matching's costs are whole multiples of its inverse
DENSE_MATCH_NODES = 120  # below this many nodes one dense assignment beats sparse bookkeeping
PAIR_FIELDS = (
    "a",
    "b",
    "r_time",
    "ratio",
    "speed_spread",
    "span",
)  # travel-time residuals beyond 3 spreads count linearly: heavy tails


class AssignmentParams(AssociatorParams):
    max_skip: int = Field(
        default=2,
        ge=0,
        le=10,
        description="Consecutive missed detections a track may bridge. Higher tolerates more "
        "misses but lets a track jump further, over more candidates.",
    )
    gate_cost: float = Field(
        default=18.0,
        gt=0,
        description="Largest cost of a link (a sum of -2 log densities of standardised "
        "residuals: r^2 in the core, flatter in the learned heavy tails, so 18 is about four "
        "core standard deviations); leaving a detection unlinked "
        "costs half of it. Lower leaves more detections as separate tracks; higher links more "
        "boldly.",
    )
    miss_cost: float = Field(
        default=6.0,
        ge=0,
        description="Extra cost per sensor skipped by a link: how much a consecutive link is "
        "preferred to a link over a missed detection.",
    )
    travel_time_spread: float = Field(
        default=0.1,
        gt=0,
        le=5,
        description="Prior relative spread (std of log) of a travel time around its kinematic "
        "prediction, before the segments' own spreads are learned.",
    )
    velocity_change_spread: float = Field(
        default=0.1,
        gt=0,
        le=5,
        description="Prior spread (std of log ratio) of the speed change between neighbouring "
        "sensors, before it is learned per segment.",
    )
    velocity_change_weight: float = Field(
        default=0.9,
        ge=0,
        le=10,
        description="Weight of the speed-change penalty against the travel-time one. Speeds "
        "change little between neighbouring sensors, even in car-following traffic; but most "
        "when targets overtake, and the travel-time term already uses both speeds. Higher "
        "trusts speed continuity more.",
    )
    preferred_speed_weight: float = Field(
        default=0.35,
        ge=0,
        le=10,
        description="Weight of the penalty on a speed far from the track's mean speed (relative "
        "to each sensor's typical speed): drivers keep their own pace, which separates targets "
        "whose speeds cross while they overtake; but in car-following traffic the car in front "
        "sets the pace. Higher trusts a driver's own pace more.",
    )
    preferred_speed_memory: float = Field(
        default=3.0,
        ge=1,
        le=100,
        description="Most detections a track's mean speed counts as independent: speed "
        "fluctuations last several sensors, so a long track's mean is not proportionally surer. "
        "Higher trusts a driver's pace more.",
    )
    velocity_change_ambiguity: float = Field(
        default=0.35,
        ge=0,
        le=5,
        description="How much an unexplained speed change widens the travel-time gate: where "
        "between two sensors a target slowed down is unknown, so its travel time is too.",
    )
    velocity_floor: float = Field(
        default=0.05,
        gt=0,
        le=1,
        description="Speeds below this share of the median speed are raised to it before "
        "predicting travel times (a target almost stopped at a sensor).",
    )
    timestamp_noise: float = Field(
        default=0.02,
        ge=0,
        description="Timestamp measurement error (std, time units): the least spread of a "
        "travel time, however short. Held to at most 2% of a typical travel time between "
        "neighbouring sensors, so the default also suits minutes or hours.",
    )
    em_rounds: int = Field(
        default=3,
        ge=0,
        le=20,
        description="Rounds of learning the segments' behaviour from the tracks and "
        "re-associating with it (0 = the kinematic prior only).",
    )
    refine_sweeps: int = Field(
        default=2,
        ge=0,
        le=10,
        description="Sweeps over the sensor boundaries re-pairing track prefixes with track "
        "suffixes, each seen whole (0 = keep the sequential pass's links).",
    )
    min_segment_samples: int = Field(
        default=8,
        ge=2,
        description="Links at which a segment's own measured spreads weigh as much as those "
        "pooled over all segments (fewer links: the pooled ones dominate). Higher makes the "
        "learned model smoother across segments.",
    )
    min_track_length: int = Field(
        default=2,
        ge=1,
        description="Tracks with fewer detections are taken for false alarms (left "
        "unassigned), unless the batch's time window explains why they are short: seen from the "
        "first sensor or since the batch began, and up to the last sensor or until it ended.",
    )
    min_track_evidence: float = Field(
        default=8.0,
        ge=0,
        description="Least total saving of a track's links over leaving its detections apart "
        "(the sum of gate_cost - link cost); weaker tracks are taken for chained false alarms. "
        "Higher drops more doubtful short tracks; 0 keeps every track.",
    )
    duplicate_window: float = Field(
        default=0.5,
        ge=0,
        description="Two reports of one sensor at most this far apart in time (time units) with "
        "near-equal speed may be one passage reported twice; only one of them joins a track. "
        "Held to at most a quarter of a typical travel time between neighbouring sensors, so "
        "the default also suits minutes or hours. 0 disables.",
    )
    duplicate_velocity_tolerance: float = Field(
        default=0.05,
        ge=0,
        le=1,
        description="Largest relative speed difference of two reports taken as a duplicate.",
    )


@dataclass
class SegmentModel:
    """Learned behaviour of the road between sensor p and sensor p + span, for every p and span.

    Arrays are indexed [p, span] (span 0 unused): log of the travel-time bias over the kinematic
    prediction, the skew of that prediction, the bias's spread, mean log speed ratio, and its
    spread. A link a -> b is predicted to take `exp(log_bias) * dx * ((1 - skew) / v_a +
    skew / v_b)`: skew 0.5 weighs both ends' speeds alike (the kinematic prediction); where
    vehicles brake or accelerate at one place, near one end, that end's speed says less about
    the travel time and the learned skew moves away from it. The spread of a track's speed
    about its own pace is one number for the road, as are the tails of the three residuals.
    """

    log_bias: FloatArray
    skew: FloatArray
    time_spread: FloatArray
    log_speed_ratio: FloatArray
    speed_spread: FloatArray
    preferred_speed_spread: float
    time_tails: Tails
    speed_tails: Tails
    level_tails: Tails

    @classmethod
    def prior(cls, s: Sensors, max_span: int, params: AssignmentParams) -> SegmentModel:
        """What the detections say before any of them is linked.

        Every segment's travel-time bias is the mode of log(observed / kinematic travel time)
        over all pairs of its end sensors' detections within a broad window: the true pairs
        pile up at the segment's bias, unrelated pairs spread thin (`_travel_time_prior`). So a
        slow zone that changes speeds at a sensor shows here, before the first link is made.
        A link over missed detections (span > 1) takes the sum of its segments' typical travel
        times: travel times add up, while between distant sensors there are many more unrelated
        pairs per true one, and the highest bump of their mode is mostly chance. The speed ratio
        is that of the sensors' median speeds; the skew is 0.5, until learned.
        """
        n_sensors = s.positions.size
        shape = (n_sensors, max_span + 1)
        span_axis = np.arange(max_span + 1, dtype=np.float64)
        log_bias = np.zeros(shape)
        log_ratio = np.zeros(shape)
        medians = s.median_speed
        for p in range(n_sensors - 1):
            # A few hundred detections, evenly spread in time, are plenty to find a mode.
            sample = s.members(p)[:: max(1, s.members(p).size // PRIOR_SAMPLE)]
            log_bias[p, 1] = _travel_time_prior(s, sample, p + 1)

        # A typical target's travel time over every segment, and its kinematic prediction.
        def kinematic(p: int, q: int) -> float:
            return float(s.positions[q] - s.positions[p]) * 0.5 * (1 / medians[p] + 1 / medians[q])

        typical = [np.exp(log_bias[p, 1]) * kinematic(p, p + 1) for p in range(n_sensors - 1)]
        for p in range(n_sensors):
            for span in range(1, min(max_span, n_sensors - 1 - p) + 1):
                q = p + span
                log_ratio[p, span] = np.log(medians[q] / medians[p])
                if span > 1:
                    log_bias[p, span] = np.log(sum(typical[p:q]) / kinematic(p, q))
        return cls(
            log_bias,
            np.full(shape, 0.5),
            np.full(shape, params.travel_time_spread),
            log_ratio,
            np.broadcast_to(
                params.velocity_change_spread * np.sqrt(np.maximum(span_axis, 1.0)), shape
            ).copy(),
            params.velocity_change_spread,
            Tails(*PRIOR_TAILS),
            Tails(*PRIOR_TAILS),
            Tails(*PRIOR_TAILS),
        )


@dataclass
class Level:
    """Mean relative speed of some track pieces, and how many detections each mean is over."""

    mean: FloatArray
    count: FloatArray


@dataclass
class TrackLevel:
    """Per detection: mean relative speed of its track up to and including it, and how many
    detections that mean is over."""

    mean: FloatArray
    count: FloatArray

    @classmethod
    def start(cls, s: Sensors) -> TrackLevel:
        return cls(s.relative_speed.copy(), np.ones(s.relative_speed.size))

    def extend(self, s: Sensors, a: IntArray, b: IntArray) -> None:
        """Detection b continues the track that ends in detection a."""
        count = self.count[a] + 1.0
        self.mean[b] = self.mean[a] + (s.relative_speed[b] - self.mean[a]) / count
        self.count[b] = count


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

    def members(self, k: int) -> IntArray:
        return self.order[self.start[k] : self.start[k + 1]]


def arrange(detections: Detections, params: AssignmentParams) -> Sensors:
    """Index the detections by sensor and time, with speeds floored (never divide by ~0)."""
    positions, sensor = np.unique(detections.position, return_inverse=True)
    sensor = sensor.astype(np.int64)
    # Ties broken by speed, then input order, so a shuffled input gives the same grouping.
    order = np.lexsort((detections.velocity, detections.timestamp, sensor)).astype(np.int64)
    start = np.searchsorted(sensor[order], np.arange(positions.size + 1)).astype(np.int64)
    floor = params.velocity_floor * float(_median(detections.velocity))
    speed = np.maximum(detections.velocity, floor)
    log_speed = np.log(speed)
    typical = np.array(
        [_median(log_speed[order[start[k] : start[k + 1]]]) for k in range(positions.size)]
    )
    return Sensors(
        positions,
        order,
        start,
        sensor,
        detections.timestamp,
        speed,
        log_speed,
        log_speed - typical[sensor],
        detections.timestamp[order],
        1.0 / speed[order],
        log_speed[order],
        np.maximum.reduceat(speed[order], start[:-1]) if order.size else np.zeros(0),
        np.array([_median(speed[order[start[k] : start[k + 1]]]) for k in range(positions.size)]),
    )


def _travel_time_prior(s: Sensors, a: IntArray, q: int) -> float:
    """A segment's log bias before anything is linked: the most common log(observed / kinematic
    travel time) of the pairs from detections a to sensor q, or 0, the kinematic prediction,
    unless the data clearly say otherwise."""
    pairs = CandidatePairs.within_reach(s, a, q)
    if pairs is None:
        return 0.0
    every = np.ones(pairs.pa.size, dtype=bool)
    if a.size < PRIOR_TEST_SAMPLE:
        # A handful of targets: no background to thin, no power for a test.
        mode = pairs.excess(every)
        return mode.centre() if mode.excess.max() > 0 else 0.0
    # A driver often keeps its place among the speeds around it, so the pairs whose speeds,
    # relative to their sensors' typical speeds, agree hold most true pairs and few unrelated
    # ones; but not where every driver brakes to a speed of its own: both selections are tried.
    change = s.relative_speed[pairs.pb] - s.relative_speed[pairs.pa]
    agree = np.abs(change) <= PRIOR_AGREEMENT * _robust(s.relative_speed[s.members(q)])[1]
    best, best_significance = 0.0, -np.inf
    for keep in (agree, every):
        mode = pairs.excess(keep)
        significance = mode.significance()
        if significance > best_significance:
            best, best_significance = mode.centre(), significance
    # The kinematic prediction stands unless another bias explains clearly more pairs: the
    # background is rough (arrivals bunch in queues, speeds mix, platoons repeat at one
    # headway), so a bump that is merely above it is no evidence of a bias.
    return best if best_significance >= PRIOR_SIGNIFICANCE else 0.0


PRIOR_BINS = np.arange(-PRIOR_LOG_RANGE, PRIOR_LOG_RANGE + PRIOR_BIN, PRIOR_BIN)
PRIOR_ZERO_BIN = int(np.searchsorted(PRIOR_BINS, 0.0) - 1)


@dataclass
class CandidatePairs:
    """Every pair (pa, pb) of a detection from sample a with a later detection at sensor q that
    the segment's prior could link: up to 10x the kinematic travel time."""

    s: Sensors
    a: IntArray
    pa: IntArray
    pb: IntArray
    length: float
    rate: float  # detections per time unit at q
    typical_inverse_b: float  # 1 / the median speed at q

    @classmethod
    def within_reach(cls, s: Sensors, a: IntArray, q: int) -> CandidatePairs | None:
        members = s.members(q)
        if members.size == 0 or a.size == 0:
            return None
        times = s.time[members]
        length = float(s.positions[q] - s.positions[s.sensor[a[0]]])
        slowest = float(s.speed[members].min())
        reach = np.exp(PRIOR_LOG_RANGE) * length * 0.5 * (1 / s.speed[a] + 1 / slowest)
        first = np.searchsorted(times, s.time[a], side="right")
        count = np.maximum(np.searchsorted(times, s.time[a] + reach) - first, 0)
        if count.sum() == 0:
            return None
        pa = np.repeat(a, count)
        pb = members[
            np.repeat(first, count)
            + np.arange(count.sum())
            - np.repeat(np.cumsum(count) - count, count)
        ]
        span_of_time = float(times[-1] - times[0])
        rate = (members.size - 1) / span_of_time if span_of_time > 0 else 0.0
        return cls(s, a, pa, pb, length, rate, 1.0 / float(_median(s.speed[members])))

    def excess(self, keep: BoolArray) -> BiasHistogram:
        """Histogram of log(observed / kinematic travel time) of the kept pairs less the
        background of unrelated pairs: those fall uniformly in time at q's rate, so their
        expected number in a bin grows as e^value (thinned as the pairs are)."""
        s, pa, pb = self.s, self.pa[keep], self.pb[keep]
        kinematic = self.length * 0.5 * (1.0 / s.speed[pa] + 1.0 / s.speed[pb])
        values = np.log((s.time[pb] - s.time[pa]) / kinematic)
        values = values[np.abs(values) <= PRIOR_LOG_RANGE]
        histogram = np.histogram(values, PRIOR_BINS)[0].astype(np.float64)
        typical = self.length * 0.5 * (1.0 / s.speed[self.a] + self.typical_inverse_b)
        background = (
            float(keep.mean()) * self.rate * float(typical.sum()) * np.diff(np.exp(PRIOR_BINS))
        )
        return BiasHistogram(
            values,
            np.convolve(histogram - background, [1.0, 2.0, 1.0], mode="same"),
            np.convolve(histogram, [1.0, 4.0, 1.0], mode="same") + 1.0,  # Poisson counts
        )


@dataclass
class BiasHistogram:
    """Pairs' log(observed / kinematic travel time): the smoothed count in each of PRIOR_BINS
    less its background (`excess`), and that count's variance."""

    values: FloatArray
    excess: FloatArray
    variance: FloatArray

    def significance(self) -> float:
        """How many standard deviations the highest excess stands above the kinematic
        prediction's own (bias 0)."""
        best = int(np.argmax(self.excess))
        if self.excess[best] <= 0:
            return -np.inf
        lead = self.excess[best] - self.excess[PRIOR_ZERO_BIN]
        return float(lead / np.sqrt(self.variance[best] + self.variance[PRIOR_ZERO_BIN]))

    def centre(self) -> float:
        """The log bias at the highest excess: the median of the values near it."""
        best = int(np.argmax(self.excess))
        peak = 0.5 * (PRIOR_BINS[best] + PRIOR_BINS[best + 1])
        near = self.values[np.abs(self.values - peak) <= 2 * PRIOR_BIN]
        return float(_median(near)) if near.size else float(peak)


@dataclass(frozen=True)
class Tails:
    """How a standardised residual strays beyond its core: a share `weight` of the residuals
    spreads `scale` times wider (a two-component normal scale mixture, fitted by EM).

    Real traffic has such tails (a driver accelerating after entering the road, a truck changing
    lanes): on SUMO's motorways the core spread of a travel time, measured robustly, is 0.5-1 %,
    yet 5 % of the travel times are 3-5 core spreads off, and speed changes are heavier-tailed
    still. A cost of r^2 calls those impossible, so it broke tracks and swapped targets; this one
    is r^2 in the core and grows only as (r / scale)^2 in the tails, which also makes one large
    change cheaper than two medium ones, as it is in traffic. The paper's simulator has no such
    tails, and there the fit leaves them negligible (weight ~0.001).
    """

    weight: float
    scale: float

    def cost(self, r: FloatArray) -> FloatArray:
        """-2 log of the mixture density, relative to its value at 0 (so r^2 when weight is 0)."""
        r2 = np.square(r)
        if self.weight <= 0:
            return r2
        w, s = self.weight, self.scale
        core = np.log1p(-w) - 0.5 * r2
        tail = np.log(w / s) - 0.5 * r2 / (s * s)
        return -2.0 * (np.logaddexp(core, tail) - np.log(1.0 - w + w / s))

    def reach(self, budget: float) -> float:
        """The largest |r| whose cost stays within `budget` (the cost grows with |r|)."""
        hi = np.sqrt(budget) * max(self.scale, 1.0)
        grid = np.linspace(0.0, hi, 513)
        inside = grid[self.cost(grid) <= budget]
        return float(inside[-1]) if inside.size else 0.0

    @classmethod
    def fit(cls, z: FloatArray, prior: Tails) -> Tails:
        """EM for the tail share and width of core-standardised residuals (the core fixed at 1,
        the tail at least TAIL_MIN_SCALE wide so it stays a tail)."""
        if z.size < TAIL_MIN_SAMPLES:
            return prior
        z2 = np.square(z[:: max(1, z.size // TAIL_SAMPLE)])  # an even sample pins the shape
        w, s = prior.weight, prior.scale
        for _ in range(TAIL_EM_ITERATIONS):
            before = (w, s)
            core = np.log1p(-w) - 0.5 * z2
            tail = np.log(w / s) - 0.5 * z2 / (s * s)
            share = np.exp(tail - np.logaddexp(core, tail))
            total = float(share.sum())
            w = float(np.clip(total / z2.size, TAIL_WEIGHT_RANGE[0], TAIL_WEIGHT_RANGE[1]))
            s = float(np.sqrt(float(share @ z2) / max(total, 1e-9)))
            s = min(max(s, TAIL_MIN_SCALE), TAIL_MAX_SCALE)
            if abs(w - before[0]) < 1e-4 and abs(s - before[1]) < 1e-3:
                break
        return cls(w, s)


@dataclass
class Pairs:
    """Candidate links a -> b with what their cost needs: the standardised travel-time error, the
    unexplained log speed change, the segment's speed spread, and the number of sensors spanned.
    """

    a: IntArray
    b: IntArray
    r_time: FloatArray
    ratio: FloatArray
    speed_spread: FloatArray
    span: IntArray

    def take(self, keep: npt.NDArray[np.bool_]) -> Pairs:
        return Pairs(
            self.a[keep],
            self.b[keep],
            self.r_time[keep],
            self.ratio[keep],
            self.speed_spread[keep],
            self.span[keep],
        )

    @classmethod
    def between(
        cls, s: Sensors, model: SegmentModel, params: AssignmentParams, a: IntArray, b: IntArray
    ) -> Pairs:
        """The given links, whatever sensors they join."""
        p = s.sensor[a]
        span = s.sensor[b] - p
        length = np.exp(model.log_bias[p, span]) * (s.positions[s.sensor[b]] - s.positions[p])
        w = model.skew[p, span]
        r_time, ratio = _time_residual(
            params,
            length * ((1.0 - w) / s.speed[a] + w / s.speed[b]),
            s.time[b] - s.time[a],
            s.log_speed[b] - s.log_speed[a] - model.log_speed_ratio[p, span],
            model.time_spread[p, span],
        )
        return cls(a, b, r_time, ratio, model.speed_spread[p, span], span)


def _time_residual(
    params: AssignmentParams,
    predicted: FloatArray,
    travel: FloatArray,
    ratio: FloatArray,
    time_spread: FloatArray,
) -> tuple[FloatArray, FloatArray]:
    """Standardised error of a travel time against the segment's prediction from both ends'
    speeds (`predicted`, see SegmentModel). The unexplained speed change `ratio` widens the
    spread: where between the sensors the speed changed is unknown, so the travel time is too."""
    ambiguity = params.velocity_change_ambiguity * ratio
    relative = np.sqrt(time_spread * time_spread + ambiguity * ambiguity)
    absolute = relative * predicted
    spread = np.sqrt(absolute * absolute + 2.0 * params.timestamp_noise**2)
    return (travel - predicted) / spread, ratio


def link_cost(
    params: AssignmentParams, model: SegmentModel, pairs: Pairs, before: Level, after: Level
) -> FloatArray:
    """Cost of every candidate link a -> b: a sum of -2 log densities of standardised residuals
    (squared in the core, flatter in the learned heavy tails: `Tails`).

    `before` is the mean relative speed (and its number of detections) of the track ending in a,
    `after` that of the track starting with b (b alone, when linking sensor by sensor)."""
    r_speed = pairs.ratio / pairs.speed_spread
    # A driver keeps a preferred speed relative to the traffic around: compare the speeds,
    # relative to their sensors' typical speed, of the two track pieces the link would join.
    # Speed fluctuations are correlated over several sensors, so a mean over many detections is
    # not as sure as 1/n would say: the counts are capped.
    memory = params.preferred_speed_memory
    level_spread = model.preferred_speed_spread * np.sqrt(
        1.0 / np.minimum(before.count, memory) + 1.0 / np.minimum(after.count, memory)
    )
    r_level = (after.mean - before.mean) / level_spread
    return (
        model.time_tails.cost(pairs.r_time)
        + params.velocity_change_weight * model.speed_tails.cost(r_speed)
        + params.preferred_speed_weight * model.level_tails.cost(r_level)
        + params.miss_cost * (pairs.span - 1)
    )


def gated_pairs(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    a: IntArray,
    q: int,
    gate: float,
) -> Pairs:
    """Candidate links from detections a to sensor q whose travel time alone is within the gate.

    The time window first allows any speed seen at q (sorted times, `searchsorted`), so the work
    is proportional to the detections near each one, never to all pairs; then, with b's speed
    known, pairs whose travel time alone costs more than the gate are dropped."""
    lo_index, hi_index = s.start[q], s.start[q + 1]
    times = s.sorted_time[lo_index:hi_index]
    if times.size == 0 or a.size == 0:
        empty = np.zeros(0, dtype=np.int64)
        none = np.zeros(0)
        return Pairs(empty, empty, none, none, none, empty)
    inverse_q = s.sorted_inverse_speed[lo_index:hi_index]
    log_q = s.sorted_log_speed[lo_index:hi_index]
    # Everything about a, once per a.
    p = s.sensor[a]
    span = q - p
    length = np.exp(model.log_bias[p, span]) * (s.positions[q] - s.positions[p])
    w = model.skew[p, span]
    # The prediction is from_a + to_b / v_b: the part of the travel time each end's speed explains.
    from_a = length * (1.0 - w) / s.speed[a]
    to_b = length * w
    centre = s.log_speed[a] + model.log_speed_ratio[p, span]
    time_spread = model.time_spread[p, span]
    # The window: any speed at q, the gate's number of spreads, the widest ambiguity.
    reach = model.time_tails.reach(gate)
    fastest, slowest = float(inverse_q.min()), float(inverse_q.max())
    worst = np.maximum(np.abs(-np.log(fastest) - centre), np.abs(-np.log(slowest) - centre))
    relative = np.sqrt(time_spread**2 + (params.velocity_change_ambiguity * worst) ** 2)
    slack = reach * params.timestamp_noise * np.sqrt(2.0)
    t_a = s.time[a]
    lo = t_a + (from_a + to_b * fastest) * np.exp(-reach * relative) - slack
    # However heavy the tails, no target covers the gap much faster than the fastest speed
    # either sensor measured: such a link is two targets' detections, never one target's.
    gap = s.positions[q] - s.positions[p]
    quickest = gap / (FASTEST_SHARE * np.maximum(s.top_speed[p], s.top_speed[q]))
    lo = np.maximum(lo, t_a + quickest - slack)
    hi = t_a + (from_a + to_b * slowest) * (1.0 + reach * relative) + slack
    first = np.searchsorted(times, lo, side="left")
    count = np.maximum(np.searchsorted(times, hi, side="right") - first, 0)
    total = int(count.sum())
    local = np.repeat(first - (np.cumsum(count) - count), count) + np.arange(total)

    def each(values: np.ndarray) -> np.ndarray:
        return np.repeat(values, count)

    r_time, ratio = _time_residual(
        params,
        each(from_a) + each(to_b) * inverse_q[local],
        times[local] - each(t_a),
        log_q[local] - each(centre),
        each(time_spread),
    )
    pair_span = each(span)
    keep = model.time_tails.cost(r_time) + params.miss_cost * (pair_span - 1) < gate
    local = local[keep]
    return Pairs(
        each(a)[keep],
        s.order[lo_index + local],
        r_time[keep],
        ratio[keep],
        each(model.speed_spread[p, span])[keep],
        pair_span[keep],
    )


def match(
    left: IntArray, right: IntArray, cost: FloatArray, gate: float
) -> tuple[IntArray, IntArray]:
    """Minimum-cost one-to-one matching of the (left, right, cost) edges, every node free to stay
    unmatched at cost gate / 2 (so an edge is taken only if it beats leaving both ends alone).

    The gated graph falls apart into many small connected components (targets far apart in
    time never compete), which are solved independently: an isolated edge is simply taken, the
    others are solved a batch of components at a time, which keeps every sparse assignment small
    (LAPJVsp's shortest-path phase costs in proportion to the graph for every free row, so one
    huge call would be quadratic).
    """
    keep = cost < gate
    left, right, cost = left[keep], right[keep], cost[keep]
    if left.size == 0:
        return left, right
    lu, li = np.unique(left, return_inverse=True)
    ru, ri = np.unique(right, return_inverse=True)
    n_l, n_r = lu.size, ru.size
    if n_l + n_r <= DENSE_MATCH_NODES:
        ml, mr = _match_dense(li, ri, cost, gate / 2.0, n_l, n_r)
        return lu[ml], ru[mr]
    graph = coo_matrix((np.ones(li.size), (li, n_l + ri)), shape=(n_l + n_r, n_l + n_r))
    n_parts, part = connected_components(graph, directed=False)
    edge_part = part[li]
    edges_in_part = np.bincount(edge_part, minlength=n_parts)
    alone = edges_in_part[edge_part] == 1
    taken_l = [li[alone]]
    taken_r = [ri[alone]]
    shared = np.flatnonzero(~alone)
    if shared.size:
        # Batches of whole components, about MATCH_BATCH edges each.
        order = shared[np.argsort(edge_part[shared], kind="stable")]
        parts = edge_part[order]
        boundary = np.flatnonzero(np.r_[True, parts[1:] != parts[:-1]])
        batch_of_part = np.cumsum(edges_in_part[parts[boundary]]) // MATCH_BATCH
        batch = np.repeat(batch_of_part, np.diff(np.r_[boundary, order.size]))
        cuts = np.flatnonzero(np.r_[True, batch[1:] != batch[:-1], True])
        for lo, hi in itertools.pairwise(cuts):
            block = order[lo:hi]
            bl, br = _match_block(li[block], ri[block], cost[block], gate / 2.0)
            taken_l.append(bl)
            taken_r.append(br)
    return lu[np.concatenate(taken_l)], ru[np.concatenate(taken_r)]


def _match_dense(
    li: IntArray, ri: IntArray, cost: FloatArray, alone: float, n_l: int, n_r: int
) -> tuple[IntArray, IntArray]:
    """The same matching as `_match_block`, as one dense square assignment, for small problems
    (a paper-sized batch): building sparse graphs and their components costs far more there.

    Rows are the lefts, then one dummy per right; columns the rights, then one dummy per left. A
    left may take a real right along an edge or its own dummy (cost `alone`); dummies pair freely
    at no cost, which always leaves exactly as many free dummy rows as free dummy columns.
    """
    square = np.full((n_l + n_r, n_r + n_l), np.inf)
    square[li, ri] = cost
    square[np.arange(n_l), n_r + np.arange(n_l)] = alone
    square[n_l + np.arange(n_r), np.arange(n_r)] = alone
    square[n_l:, n_r:] = 0.0
    row, col = linear_sum_assignment(square)
    real = (row < n_l) & (col < n_r)
    return row[real], col[real]


def _match_block(
    left: IntArray, right: IntArray, cost: FloatArray, alone: float
) -> tuple[IntArray, IntArray]:
    """Exact min-cost matching of some edges, each node free to stay unmatched at cost `alone`.

    Sparse LAPJVsp on the graph augmented with one dummy node per real node: left l may match its
    own dummy (stay alone), right r may match its own dummy, and dummies match each other along
    every real edge so a full matching always exists.
    """
    lu, li = np.unique(left, return_inverse=True)
    ru, ri = np.unique(right, return_inverse=True)
    n_l, n_r = lu.size, ru.size
    # rows: real lefts [0, n_l), dummies of rights [n_l, n_l + n_r)
    # cols: real rights [0, n_r), dummies of lefts [n_r, n_r + n_l)
    rows = np.concatenate([li, np.arange(n_l), n_l + np.arange(n_r), n_l + ri])
    cols = np.concatenate([ri, n_r + np.arange(n_l), np.arange(n_r), n_r + li])
    # All weights shifted by +1: LAPJVsp needs non-zero weights, a full matching has a fixed
    # number of edges, so the shift changes nothing.
    weights = np.concatenate([cost, np.full(n_l, alone), np.full(n_r, alone), np.zeros(ri.size)])
    # ... and rounded to whole multiples of 2^-10, so that every sum LAPJVsp forms is exact: with
    # arbitrary floats its rounding errors can make it cycle forever (seen on a dense block of
    # SUMO traffic; tests/data/lapjvsp_cycle.npz). The rounding changes costs by < 0.001.
    weights = np.round(weights * COST_QUANTUM_INVERSE) / COST_QUANTUM_INVERSE
    graph = csr_matrix((weights + 1.0, (rows, cols)), shape=(n_l + n_r, n_r + n_l))
    graph.sum_duplicates()
    row, col = min_weight_full_bipartite_matching(graph)
    real = (row < n_l) & (col < n_r)
    return lu[row[real]], ru[col[real]]


def duplicate_followers(s: Sensors, params: AssignmentParams) -> IntArray:
    """For every detection, the earlier report of the same sensor it may duplicate (-1 if none):
    within `duplicate_window` in time and `duplicate_velocity_tolerance` in speed."""
    n = s.time.size
    leader = np.full(n, -1, dtype=np.int64)
    if params.duplicate_window <= 0:
        return leader
    tol = np.log1p(params.duplicate_velocity_tolerance)
    for k in range(s.positions.size):
        m = s.members(k)
        for lag in range(1, m.size):
            later, earlier = m[lag:], m[:-lag]
            close = s.time[later] - s.time[earlier] <= params.duplicate_window
            if not close.any():
                break
            alike = close & (np.abs(s.log_speed[later] - s.log_speed[earlier]) <= tol)
            fresh = alike & (leader[later] < 0)
            leader[later[fresh]] = earlier[fresh]
    return leader


def build_tracks(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    leader: IntArray,
    progress: Progress | None,
    done: float,
    share: float,
) -> IntArray:
    """One sequential pass over the sensors: the track index of every detection (-1 = none)."""
    n = s.time.size
    n_sensors = s.positions.size
    track = np.full(n, -1, dtype=np.int64)
    level = TrackLevel.start(s)
    tail = np.zeros(0, dtype=np.int64)  # last detection of every track, by track index
    for q in range(n_sensors):
        members = s.members(q)
        linked_b = np.zeros(0, dtype=np.int64)
        if q > 0 and tail.size:
            open_tails = tail[s.sensor[tail] >= q - 1 - params.max_skip]
            pairs = gated_pairs(s, model, params, open_tails, q, params.gate_cost)
            if pairs.a.size:
                a, b = pairs.a, pairs.b
                before = Level(level.mean[a], level.count[a])
                after = Level(s.relative_speed[b], np.ones(b.size))
                cost = link_cost(params, model, pairs, before, after)
                linked_a, linked_b = match(a, b, cost, params.gate_cost)
                level.extend(s, linked_a, linked_b)
                track[linked_b] = track[linked_a]
                tail[track[linked_b]] = linked_b
        # Births: unmatched detections, except a report that may duplicate one just linked
        # (same sensor, moments apart, same speed): one passage reported twice must not start a
        # second track. Two such reports both unmatched both start tracks, since they may be two
        # vehicles side by side; a copy's track then dies short (`min_track_length`).
        unmatched = members[track[members] < 0]
        twin_linked = np.zeros(n, dtype=bool)
        copies = linked_b[leader[linked_b] >= 0]
        twin_linked[leader[copies]] = True
        lead = leader[unmatched]
        twin_linked[unmatched[lead >= 0]] |= track[lead[lead >= 0]] >= 0
        born = unmatched[~twin_linked[unmatched]]
        track[born] = tail.size + np.arange(born.size)
        tail = np.concatenate([tail, born])
        if progress:
            progress(done + share * (q + 1) / n_sensors)
    return track


def successors(s: Sensors, track: IntArray) -> tuple[IntArray, IntArray]:
    """The next and previous detection of every detection in its track (-1 = none)."""
    n = track.size
    nxt = np.full(n, -1, dtype=np.int64)
    prv = np.full(n, -1, dtype=np.int64)
    assigned = np.flatnonzero(track >= 0)
    chain = assigned[np.lexsort((s.sensor[assigned], track[assigned]))]
    same = track[chain[1:]] == track[chain[:-1]]
    nxt[chain[:-1][same]] = chain[1:][same]
    prv[chain[1:][same]] = chain[:-1][same]
    return nxt, prv


def tracks_from_links(s: Sensors, prv: IntArray, in_track: BoolArray) -> IntArray:
    """Track index of every detection from its predecessor links (-1 where not in a track)."""
    track = np.full(prv.size, -1, dtype=np.int64)
    count = 0
    for k in range(s.positions.size):
        members = s.members(k)
        members = members[in_track[members]]
        linked = prv[members] >= 0
        track[members[linked]] = track[prv[members[linked]]]
        first = members[~linked]
        track[first] = count + np.arange(first.size)
        count += first.size
    return track


def refine_boundaries(
    s: Sensors, model: SegmentModel, params: AssignmentParams, track: IntArray
) -> IntArray:
    """Re-pair the tracks across every sensor boundary, seeing both sides whole.

    The sequential pass chooses each link knowing only the past. Here, boundary after boundary,
    every track is cut before sensor k into a prefix and a suffix, and prefixes are matched to
    suffixes again with the same link cost, its speed-level term now comparing the prefix's mean
    speed with the suffix's. This undoes swaps between targets that crossed at near-equal speeds
    and joins fragments a failed link split (a prefix without a suffix meets a suffix without a
    prefix). Each boundary costs time in proportion to the detections near it.
    """
    nxt, prv = successors(s, track)
    in_track = track >= 0
    reach = params.max_skip + 1
    n_sensors = s.positions.size
    u = s.relative_speed
    # Suffix sums (from a detection to its track's end), accumulated backwards. A suffix only
    # involves links after its head, which this sweep has not reached yet, so they stay valid.
    tail_sum = np.where(in_track, u, 0.0)
    tail_count = in_track.astype(np.float64)
    for k in range(n_sensors - 1, -1, -1):
        m = s.members(k)
        m = m[nxt[m] >= 0]
        tail_sum[m] += tail_sum[nxt[m]]
        tail_count[m] += tail_count[nxt[m]]
    is_head = np.zeros(s.time.size, dtype=bool)
    # Prefix sums (from the track's start to a detection), final once the sweep passes it.
    head_sum = np.where(in_track, u, 0.0)
    head_count = in_track.astype(np.float64)
    for k in range(1, n_sensors + 1):
        # Detections at sensor k - 1 got their final predecessor at the previous boundary.
        m = s.members(k - 1)
        m = m[prv[m] >= 0]
        head_sum[m] = u[m] + head_sum[prv[m]]
        head_count[m] = 1.0 + head_count[prv[m]]
        if k == n_sensors:
            break
        before = np.concatenate([s.members(q) for q in range(max(0, k - reach), k)])
        tails = before[
            in_track[before] & ((nxt[before] < 0) | (s.sensor[np.maximum(nxt[before], 0)] >= k))
        ]
        after = np.concatenate([s.members(q) for q in range(k, min(n_sensors, k + reach))])
        heads = after[
            in_track[after] & ((prv[after] < 0) | (s.sensor[np.maximum(prv[after], 0)] < k))
        ]
        if tails.size == 0 or heads.size == 0:
            continue
        is_head[heads] = True
        found: list[Pairs] = []
        for q in range(k, min(k + reach, n_sensors)):
            near = tails[s.sensor[tails] >= q - reach]
            pairs = gated_pairs(s, model, params, near, q, REFINE_GATE_FACTOR * params.gate_cost)
            found.append(pairs.take(is_head[pairs.b]))
        is_head[heads] = False
        pairs = Pairs(*(np.concatenate([getattr(f, name) for f in found]) for name in PAIR_FIELDS))
        a, b = pairs.a, pairs.b
        cost = link_cost(
            params,
            model,
            pairs,
            Level(head_sum[a] / head_count[a], head_count[a]),
            Level(tail_sum[b] / tail_count[b], tail_count[b]),
        )
        # Splitting a track costs more here than declining a link did: a track the forward pass
        # built is evidence in itself, so re-pairing must pay for itself.
        linked_a, linked_b = match(a, b, cost, REFINE_GATE_FACTOR * params.gate_cost)
        crossing = tails[nxt[tails] >= 0]
        prv[nxt[crossing]] = -1
        nxt[crossing] = -1
        nxt[linked_a] = linked_b
        prv[linked_b] = linked_a
    return tracks_from_links(s, prv, in_track)


def learn_segments(
    s: Sensors, track: IntArray, params: AssignmentParams, prior: SegmentModel
) -> SegmentModel:
    """Fit every segment's model from the detections of tracks with at least three detections:
    medians for the biases, 1.4826 x MAD for the spreads (robust to the odd wrong link)."""
    n_sensors = s.positions.size
    max_span = prior.log_bias.shape[1] - 1
    prior = SegmentModel(
        prior.log_bias.copy(),
        prior.skew.copy(),
        prior.time_spread.copy(),
        prior.log_speed_ratio.copy(),
        prior.speed_spread.copy(),
        prior.preferred_speed_spread,
        prior.time_tails,
        prior.speed_tails,
        prior.level_tails,
    )
    links_a: list[IntArray] = []
    links_b: list[IntArray] = []
    assigned = np.flatnonzero(track >= 0)
    sizes = np.bincount(track[assigned])
    confident = assigned[sizes[track[assigned]] >= 3]
    # Detections of a track in road order: sort by (track, sensor).
    chain = confident[np.lexsort((s.sensor[confident], track[confident]))]
    for span in range(1, max_span + 1):
        if chain.size <= span:
            continue
        a, b = chain[:-span], chain[span:]
        same = track[a] == track[b]
        a, b = a[same], b[same]
        p = s.sensor[a]
        gap = s.sensor[b] - p
        within = gap == span
        a, b, p = a[within], b[within], p[within]
        dt = s.time[b] - s.time[a]
        ok = dt > 0
        a, b, p, dt = a[ok], b[ok], p[ok], dt[ok]
        if a.size < params.min_segment_samples:
            continue  # keep the prior for this span
        links_a.append(a)
        links_b.append(b)
        dx = s.positions[s.sensor[b]] - s.positions[p]
        ratio = s.log_speed[b] - s.log_speed[a]
        counts = np.bincount(p, minlength=n_sensors)
        seen = np.flatnonzero(counts)
        weight = counts / (counts + params.min_segment_samples)
        skew = np.full(n_sensors, 0.5)
        for k in seen:
            here = p == k
            skew[k] = 0.5 + weight[k] * (
                _best_skew(dt[here], dx[here], s.speed[a[here]], s.speed[b[here]]) - 0.5
            )
        prior.skew[:, span] = skew
        w_link = skew[p]
        log_bias = np.log(dt / (dx * ((1.0 - w_link) / s.speed[a] + w_link / s.speed[b])))
        # Spreads pooled over all segments, each residual taken from its own segment's median.
        bias_centre = np.zeros(n_sensors)
        ratio_centre = np.zeros(n_sensors)
        for k in seen:
            bias_centre[k] = _median(log_bias[p == k])
            ratio_centre[k] = _median(ratio[p == k])
        pooled_time = _robust(log_bias - bias_centre[p])[1]
        pooled_speed = _robust(ratio - ratio_centre[p])[1]
        # Each segment's spreads are shrunk towards the pooled ones by its number of links (a
        # segment seen by ten targets must not get a spread measured on ten numbers alone); its
        # centres towards the prior's by precision (the prior is a rough guess, so a handful of
        # links overrule it).
        for k in seen:
            here = p == k
            w, n_k = weight[k], counts[k]
            own_time = _robust(log_bias[here])[1]
            own_speed = _robust(ratio[here])[1]
            time_spread = np.sqrt(w * own_time**2 + (1 - w) * pooled_time**2)
            speed_spread = np.sqrt(w * own_speed**2 + (1 - w) * pooled_speed**2)
            prior.log_bias[k, span] = _posterior_centre(
                bias_centre[k], time_spread, n_k, prior.log_bias[k, span], params.travel_time_spread
            )
            prior.log_speed_ratio[k, span] = _posterior_centre(
                ratio_centre[k],
                speed_spread,
                n_k,
                prior.log_speed_ratio[k, span],
                params.velocity_change_spread,
            )
            prior.time_spread[k, span] = time_spread
            prior.speed_spread[k, span] = speed_spread
        unseen = counts == 0
        prior.time_spread[unseen, span] = pooled_time
        prior.speed_spread[unseen, span] = pooled_speed
    if confident.size:
        members = track[confident]
        _, which = np.unique(members, return_inverse=True)
        mean = np.bincount(which, s.relative_speed[confident]) / np.bincount(which)
        deviation = s.relative_speed[confident] - mean[which]
        prior.preferred_speed_spread = _robust(deviation)[1]
    prior.preferred_speed_spread = max(prior.preferred_speed_spread, MIN_RELATIVE_SPREAD)
    # A learned spread is never trusted below these: sensors measure to a per cent at best.
    np.maximum(prior.time_spread, MIN_RELATIVE_SPREAD, out=prior.time_spread)
    np.maximum(prior.speed_spread, MIN_RELATIVE_SPREAD, out=prior.speed_spread)
    if links_a:
        # The tails, measured in the units the costs use on an even sample of the links (they
        # are one shape for the whole road, and a million links' residuals would cost memory).
        a_all, b_all = np.concatenate(links_a), np.concatenate(links_b)
        step = max(1, a_all.size // TAIL_SAMPLE)
        links = Pairs.between(s, prior, params, a_all[::step], b_all[::step])
        prior.time_tails = Tails.fit(links.r_time, prior.time_tails)
        prior.speed_tails = Tails.fit(links.ratio / links.speed_spread, prior.speed_tails)
    if confident.size:
        prior.level_tails = Tails.fit(deviation / prior.preferred_speed_spread, prior.level_tails)
    return prior


SKEW_GRID = np.linspace(0.0, 1.0, 21)
SKEW_SAMPLE = 400


def _best_skew(dt: FloatArray, dx: FloatArray, speed_a: FloatArray, speed_b: FloatArray) -> float:
    """The share w of a segment's travel time best predicted from its far end's speed:
    travel = bias * dx * ((1 - w) / v_a + w / v_b) with the least robust spread of log errors.
    Where speeds change at a known place (braking for a slow zone just before its sensor), one
    end's speed explains most of the time."""
    if dt.size < 3:
        return 0.5
    # An even sample of a few hundred links pins the skew as well as all of them would.
    step = max(1, dt.size // SKEW_SAMPLE)
    dt, dx, speed_a, speed_b = dt[::step], dx[::step], speed_a[::step], speed_b[::step]
    pace_a = (dx / speed_a)[:, None]
    pace_b = (dx / speed_b)[:, None]
    errors = np.log(dt[:, None] / ((1.0 - SKEW_GRID) * pace_a + SKEW_GRID * pace_b))
    centred = errors - np.median(errors, axis=0)
    spread = np.median(np.abs(centred), axis=0)
    best = int(np.argmin(spread))
    # The symmetric prediction stands unless another share is clearly better: beyond the
    # sampling error of a spread measured on this many links.
    symmetric = spread[SKEW_GRID.size // 2]
    if spread[best] > symmetric * (1.0 - 2.0 / np.sqrt(dt.size)):
        return 0.5
    return float(SKEW_GRID[best])


def _posterior_centre(
    measured: float, spread: float, count: int, prior: float, prior_spread: float
) -> float:
    """Precision-weighted mean of a measured centre (from `count` values) and a prior guess."""
    data_precision = count / max(spread, MIN_RELATIVE_SPREAD) ** 2
    prior_precision = 1.0 / prior_spread**2
    return (data_precision * measured + prior_precision * prior) / (
        data_precision + prior_precision
    )


def _median(values: npt.ArrayLike) -> float:
    """np.median of a 1-D array, for the many small arrays this module summarises: sorting a
    short Python list is ten times faster than numpy's general median machinery there."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    n = array.size
    if n == 0 or n > 64:
        return float(np.median(array))
    ordered = sorted(array.tolist())
    mid = n // 2
    return ordered[mid] if n % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


def _robust(values: FloatArray) -> tuple[float, float]:
    """Median and normal-consistent MAD."""
    centre = float(_median(values))
    return centre, 1.4826 * float(_median(np.abs(values - centre)))


def starts_explained(s: Sensors, model: SegmentModel, first: IntArray) -> BoolArray:
    """Whether a track starting with detection `first` needs no missed detection to explain its
    start: it is at the first sensor, or the batch began too recently for its target to have
    passed the previous sensor inside it."""
    p = s.sensor[first]
    before = np.maximum(p - 1, 0)
    return (p == 0) | (s.time[first] - _longest_travel(s, model, first, before) < s.time.min())


def ends_explained(s: Sensors, model: SegmentModel, last: IntArray) -> BoolArray:
    """Whether a track ending with detection `last` needs no missed detection to explain its
    end: it is at the last sensor, or the batch ended too soon for its target to reach the
    next one inside it."""
    p = s.sensor[last]
    final = s.positions.size - 1
    after = np.minimum(p, max(final - 1, 0))
    return (p == final) | (s.time[last] + _longest_travel(s, model, last, after) > s.time.max())


def _longest_travel(s: Sensors, model: SegmentModel, a: IntArray, p: IntArray) -> FloatArray:
    """Longest plausible travel time of detection a's target over the segment p -> p + 1."""
    gap = s.positions[np.minimum(p + 1, s.positions.size - 1)] - s.positions[p]
    return gap * np.exp(model.log_bias[p, 1] + 2.0 * model.time_spread[p, 1]) / s.speed[a]


def finish(s: Sensors, model: SegmentModel, params: AssignmentParams, track: IntArray) -> IntArray:
    """Keep the tracks that are better explained as targets than as false alarms; number them.

    A track's evidence is what its links save over leaving their detections apart: the sum of
    (gate_cost - link cost). A few false alarms can chain up through loose, sensor-skipping
    links; their evidence stays small, a real target's does not. A track shorter than
    `min_track_length` is kept only when the batch's time window explains its shortness: the
    batch cut it off at both ends (`starts_explained`, `ends_explained`), as it does a vehicle
    that passed the first sensor in its last seconds.
    """
    out = np.full(track.size, -1, dtype=np.int64)
    assigned = np.flatnonzero(track >= 0)
    if assigned.size == 0:
        return out
    chain = assigned[np.lexsort((s.sensor[assigned], track[assigned]))]
    ids = track[chain]
    linked = np.flatnonzero(ids[1:] == ids[:-1])
    a, b = chain[linked], chain[linked + 1]
    # The track's mean relative speed up to a, as the forward pass saw it.
    u = s.relative_speed[chain]
    start = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    run = np.cumsum(np.r_[True, ids[1:] != ids[:-1]]) - 1
    cumulative = np.cumsum(u)
    offset = np.where(start > 0, cumulative[np.maximum(start - 1, 0)], 0.0)[run]
    position = np.arange(chain.size) - start[run] + 1.0
    prefix_mean = (cumulative - offset) / position
    before = Level(prefix_mean[linked], position[linked])
    after = Level(s.relative_speed[b], np.ones(b.size))
    pairs = Pairs.between(s, model, params, a, b)
    saving = params.gate_cost - link_cost(params, model, pairs, before, after)
    evidence = np.bincount(ids[linked], weights=np.maximum(saving, 0.0), minlength=ids.max() + 1)
    sizes = np.bincount(ids)
    # Links are judged by their evidence; a lone detection has none to judge, only its place.
    convincing = (evidence >= params.min_track_evidence) | (sizes == 1)
    end = np.r_[start[1:], chain.size] - 1
    long_enough = sizes >= params.min_track_length
    long_enough[ids[start]] |= starts_explained(s, model, chain[start]) & ends_explained(
        s, model, chain[end]
    )
    good = convincing & long_enough
    keep = chain[good[ids]]
    _, out[keep] = np.unique(track[keep], return_inverse=True)
    return out


# The parameters in time units are held to these shares of a typical travel time between
# neighbouring sensors.
DUPLICATE_WINDOW_SHARE = 0.25
TIMESTAMP_NOISE_SHARE = 0.02


def within_time_scale(params: AssignmentParams, s: Sensors) -> AssignmentParams:
    """The parameters, with those in time units (`duplicate_window`, `timestamp_noise`) held to
    a share of a typical travel time between neighbouring sensors.

    Units are the caller's. Their defaults (0.5 and 0.02) are seconds-sized; a deployment that
    times in minutes or hours (positions in km, speeds in km/h) would otherwise take every
    report within half an hour for a duplicate, and a timestamp error of a minute for noise.
    With seconds and road traffic the limits are far above the defaults and change nothing."""
    gaps = np.diff(s.positions)
    speeds = s.median_speed
    if gaps.size == 0:
        return params
    typical = float(np.median(gaps * 0.5 * (1.0 / speeds[:-1] + 1.0 / speeds[1:])))
    return params.model_copy(
        update={
            "duplicate_window": min(params.duplicate_window, DUPLICATE_WINDOW_SHARE * typical),
            "timestamp_noise": min(params.timestamp_noise, TIMESTAMP_NOISE_SHARE * typical),
        }
    )


class AssignmentAssociator(Associator):
    name: ClassVar[str] = "assignment"
    description: ClassVar[str] = (
        "Constraint-aware tracking: links each sensor's detections to the tracks of the previous "
        "sensors by sparse minimum-cost assignment with a kinematic cost, bridging missed "
        "detections, then learns each road segment's travel-time behaviour and re-associates. "
        "At most one detection per sensor per target; false alarms stay unassigned; needs no "
        "labels and no target count."
    )
    Params = AssignmentParams
    params: AssignmentParams

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        s = arrange(detections, self.params)
        p = within_time_scale(self.params, s)
        max_span = p.max_skip + 1
        prior = SegmentModel.prior(s, max_span, p)
        model = prior
        leader = duplicate_followers(s, p)
        rounds = p.em_rounds + 1
        # Every pass (a linking round or a re-pairing sweep) visits each sensor once and costs
        # about the same: progress is the share of passes done.
        passes = rounds + p.refine_sweeps
        track = np.zeros(0, dtype=np.int64)
        for r in range(rounds):
            track = build_tracks(s, model, p, leader, progress, r / passes, 1.0 / passes)
            if r + 1 < rounds:
                model = learn_segments(s, track, p, prior)
        for sweep in range(p.refine_sweeps):
            track = refine_boundaries(s, model, p, track)
            if progress:
                progress((rounds + sweep + 1) / passes)
        return finish(s, model, p, track)
