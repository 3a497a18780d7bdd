"""What the detections say about every segment before any of them is linked (the EM's start)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.features import prior_features
from roadlink.association.associators.assignment.model import SegmentModel, Tails
from roadlink.association.associators.assignment.params import (
    PRIOR_AGREEMENT,
    PRIOR_BACKGROUND_PAIRS,
    PRIOR_BIN,
    PRIOR_KINEMATIC_BUMP,
    PRIOR_KINEMATIC_LEAD,
    PRIOR_LOG_RANGE,
    PRIOR_MIN_DETECTIONS,
    PRIOR_PEAK_BINS,
    PRIOR_PSEUDO_COUNT,
    PRIOR_SAMPLE,
    PRIOR_SIDEBAND_STEPS,
    PRIOR_SIDEBANDS,
    PRIOR_SIGNIFICANCE,
    PRIOR_SMOOTHING,
    PRIOR_STEP_BINS,
    PRIOR_TAILS,
    PRIOR_TEST_SAMPLE,
    PRIOR_WEAK_SIGNIFICANCE,
    PRIOR_WEAK_SUPPORT,
    AssignmentParams,
)
from roadlink.association.associators.assignment.robust import median, run_medians, spread
from roadlink.association.associators.assignment.sensors import (
    KINEMATIC_SKEW,
    Sensors,
    travel_time,
)
from roadlink.association.associators.assignment.weak_bias import confirmed_bias, explained_biases
from roadlink.association.detections import FloatArray, IntArray

BoolArray = npt.NDArray[np.bool_]

PRIOR_BINS = np.arange(-PRIOR_LOG_RANGE, PRIOR_LOG_RANGE + PRIOR_BIN, PRIOR_BIN)
PRIOR_ZERO_BIN = int(np.searchsorted(PRIOR_BINS, 0.0) - 1)
# Each bin's share of a uniform background (`excess_over_uniform`), and the smoothing's weights
# of a count's variance: constants, worked out once.
PRIOR_BIN_GROWTH = np.diff(np.exp(PRIOR_BINS))
PRIOR_SMOOTHING_SQUARED = np.square(PRIOR_SMOOTHING)


def segment_prior(s: Sensors, max_span: int, params: AssignmentParams) -> SegmentModel:
    """What the detections say before any of them is linked. Every segment's travel-time bias
    is the mode of log(observed / kinematic travel time) over all pairs of its end sensors'
    detections within a broad window: the true pairs pile up at the segment's bias, unrelated
    pairs spread thin (`travel_time_bumps`). So a slow zone that changes speeds at a sensor
    shows here, before the first link is made. A link over missed detections (span > 1) takes
    the sum of its segments' typical travel times: travel times add up, while between distant
    sensors there are many more unrelated pairs per true one, and the highest bump of their
    mode is mostly chance. Speed ratios are the sensors' median speeds'; skews kinematic, until
    learned. Times stamped in coarse steps are spread within them first (`Sensors.within_step`).
    """
    s = s.within_step(PRIOR_STEP_BINS * PRIOR_BIN)
    n_sensors = s.positions.size
    shape = (n_sensors, max_span + 1)
    span_axis = np.arange(max_span + 1, dtype=np.float64)
    log_bias = np.zeros(shape)
    log_ratio = np.zeros(shape)
    seen = np.diff(s.start)
    medians = s.typical_speed
    # A few hundred detections, evenly spread in time, are plenty to find a mode.
    samples = [
        s.members(p)[:: max(1, s.members(p).size // PRIOR_SAMPLE)] for p in range(n_sensors - 1)
    ]
    tested = [tested_segment(s, sample, p) for p, sample in enumerate(samples)]
    confirmed: dict[int, tuple[float, float]] = {}
    for p in np.flatnonzero(tested).tolist():
        log_bias[p, 1], by_matching = travel_time_bumps(s, samples[p], p + 1, params)
        if by_matching is not None:
            confirmed[p] = by_matching
    few = np.flatnonzero(~np.array(tested, dtype=bool)).tolist()
    log_bias[few, 1] = few_targets_priors(s, [samples[p] for p in few], np.array(few) + 1)
    # A mode needs true pairs to pile up: where either sensor saw only a vehicle or two (it
    # failed, or came online at the batch's end), the one bin a pair falls in is as high as any,
    # and the kinematic prediction stands.
    log_bias[:-1, 1][np.minimum(seen[:-1], seen[1:]) < PRIOR_MIN_DETECTIONS] = 0.0

    # A typical target's travel time over every segment, and its kinematic prediction; every
    # segment of a span at once (the same numbers as segment by segment: the sums add the
    # segments' times in road order, as `sum` did).
    def kinematic(span: int) -> FloatArray:
        p = np.arange(n_sensors - span)
        return travel_time(s.positions[p + span] - s.positions[p], medians[p], medians[p + span])

    def pairs(p: int) -> CandidatePairs | None:  # a handful of targets tests no calibration
        return CandidatePairs.within_reach(s, samples[p], p + 1) if tested[p] else None

    one_segment = kinematic(1)
    explained = explained_biases(
        confirmed, log_bias[:-1, 1], one_segment, s.calibration_speed, pairs, params
    )
    for segment, bias in explained.items():
        log_bias[segment, 1] = bias
    typical = np.exp(log_bias[:-1, 1]) * one_segment
    total = typical
    for span in range(1, min(max_span, n_sensors - 1) + 1):
        log_ratio[: n_sensors - span, span] = np.log(medians[span:] / medians[:-span])
        if span > 1:
            total = total[:-1] + typical[span - 1 :]
            log_bias[: n_sensors - span, span] = np.log(total / kinematic(span))
    return SegmentModel(
        log_bias,
        np.full(shape, KINEMATIC_SKEW),
        np.full(shape, params.travel_time_spread),
        log_ratio,
        np.broadcast_to(
            params.velocity_change_spread * np.sqrt(np.maximum(span_axis, 1.0)), shape
        ).copy(),
        params.velocity_change_spread,
        Tails(*PRIOR_TAILS),
        Tails(*PRIOR_TAILS),
        Tails(*PRIOR_TAILS),
        None if s.features is None else prior_features(s.features, s.sensor, n_sensors, max_span),
    )


def tested_segment(s: Sensors, sample: IntArray, p: int) -> bool:
    """Whether the prior of the segment from sensor p must pass the significance test
    (`travel_time_bumps`): where its sample holds PRIOR_TEST_SAMPLE detections, or sensor p is
    sparse (`Sensors.sparse`): against a busy neighbour's arrivals, which bunch by chance far
    above a handful of true pairs (SUMO's dense traffic, a sensor quiet after its first 25
    detections: a mode of 6 times the kinematic travel time, 68 % of the detections right)."""
    return sample.size >= PRIOR_TEST_SAMPLE or bool(s.sparse[p])


def travel_time_bumps(
    s: Sensors, a: IntArray, q: int, params: AssignmentParams
) -> tuple[float, tuple[float, float] | None]:
    """A segment's log bias before anything is linked: the most common log(observed / kinematic
    travel time) of the pairs from detections a to sensor q, or 0, the kinematic prediction,
    unless the data clearly say otherwise; and a bias that the pairs show less clearly but
    matching the detections confirms (`weak_bias.confirmed_bias`), where there is one:
    `segment_prior` keeps it only where a neighbouring segment mirrors it
    (`weak_bias.clock_shifts`)."""
    pairs = CandidatePairs.within_reach(s, a, q)
    if pairs is None:
        return 0.0, None
    every = np.ones(pairs.pa.size, dtype=bool)
    if not tested_segment(s, a, q - 1):
        # A handful of targets: no background to thin, no power for a test, and too few pairs
        # to move (`excess`): the background is a uniform arrival rate.
        mode = pairs.excess_over_uniform(every, pairs.log_ratios(every)[0])
        return (0.0 if mode.kinematic_stands() else mode.centre()), None
    # A driver often keeps its place among the speeds around it, so the pairs whose speeds,
    # relative to their sensors' typical speeds, agree hold most true pairs and few unrelated
    # ones; but not where every driver brakes to a speed of its own: both selections are tried.
    change = s.relative_speed[pairs.pb] - s.relative_speed[pairs.pa]
    relative_spread = spread(s.relative_speed[s.members(q)])
    agree = np.abs(change) <= PRIOR_AGREEMENT * relative_spread
    bumps = [pairs.bias(keep) for keep in (agree, every)]
    best, best_significance = max(bumps, key=lambda bump: bump[1])
    # The kinematic prediction stands unless another bias explains clearly more pairs: the
    # background is rough (arrivals bunch in queues, speeds mix, platoons repeat at one
    # headway), so a bump that is merely above it is no evidence of a bias.
    if best_significance >= PRIOR_SIGNIFICANCE:
        return best, None
    # A weaker bump counts where both selections show it in one place (a chance bump of the
    # speed-agreeing pairs is seldom one of all pairs too) and matching confirms it.
    together = all(
        abs(centre - best) <= PRIOR_PEAK_BINS * PRIOR_BIN and significance >= PRIOR_WEAK_SUPPORT
        for centre, significance in bumps
    )
    if best_significance < PRIOR_WEAK_SIGNIFICANCE or not together:
        return 0.0, None
    return 0.0, confirmed_bias(pairs, best, params)


def few_targets_priors(s: Sensors, samples: list[IntArray], q: IntArray) -> FloatArray:
    """`travel_time_bumps(s, samples[k], q[k], params)[0]` of segments of a handful of targets
    (not `tested_segment`), the same numbers: their candidate pairs and histograms worked out
    for all those segments at once (a paper-size batch paid numpy's fixed costs segment after
    segment), then each segment's mode, as `excess_over_uniform` finds it keeping every pair,
    unless the kinematic prediction stands (`BiasHistogram.kinematic_stands`)."""
    prior = np.zeros(q.size)
    ready = [k for k in range(q.size) if samples[k].size]
    if not ready:
        return prior
    few = FewPairs.of(s, [samples[k] for k in ready], q[ready])
    n = len(ready)
    counts = bin_counts(few.values, few.value_of, n).reshape(n, PRIOR_BINS.size - 1)
    some = few.pairs.nonzero()[0].tolist()
    if not some:
        return prior
    excess = np.empty((len(some), PRIOR_BINS.size - 1))
    stands = np.zeros(len(some), dtype=bool)
    for row, k in enumerate(some):
        thinning = 1.0 if few.any_ahead[k] else 0.0
        background = thinning * few.rates[k] * few.typical_sums[k] * PRIOR_BIN_GROWTH
        histogram = BiasHistogram.of(np.zeros(0), background, counts[k])
        excess[row] = histogram.excess
        stands[row] = histogram.kinematic_stands()
    # Each mode as `BiasHistogram.centre` finds it, for all segments at once.
    seen = ~stands
    modes = excess_centres(few.values, few.value_of, np.array(some)[seen], excess[seen], n)
    prior[np.array(ready)[np.array(some)[seen]]] = modes
    return prior


def excess_centres(
    values: FloatArray, value_of: IntArray, which: IntArray, excess: FloatArray, n: int
) -> FloatArray:
    """`BiasHistogram(values of k, excess[i], ...).centre()` of each segment k = which[i]: the
    median of its values near its highest excess, or that bin's middle where none is near
    (`values` run segment by segment, `value_of` saying whose; `n` segments in all)."""
    best = excess.argmax(axis=1)
    peak = np.zeros(n)
    peak[which] = 0.5 * (PRIOR_BINS[best] + PRIOR_BINS[best + 1])
    mine = np.zeros(n, dtype=bool)
    mine[which] = True
    near = np.abs(values - peak[value_of]) <= PRIOR_PEAK_BINS * PRIOR_BIN
    near &= mine[value_of]
    sizes = np.bincount(value_of[near], minlength=n)[which]
    centre = peak[which]
    some = sizes > 0
    if some.any():
        medians = run_medians(values[near], sizes[some])
        if medians is None:
            runs = np.split(values[near], np.cumsum(sizes[some])[:-1])
            medians = np.array([median(run) for run in runs])
        centre[some] = medians
    return centre


@dataclass
class FewPairs:
    """`CandidatePairs.within_reach` and `log_ratios` of several segments at once: the log
    ratios within range (`values`, segment by segment) and each one's segment (`value_of`);
    each segment's number of pairs, whether one is ahead in time, its rate of arrivals and the
    sum of its sample's typical travel times."""

    values: FloatArray
    value_of: IntArray
    pairs: IntArray
    any_ahead: BoolArray
    rates: list[float]
    typical_sums: list[float]

    @classmethod
    def of(cls, s: Sensors, samples: list[IntArray], q: IntArray) -> FewPairs:
        sizes = np.array([sample.size for sample in samples])
        bounds = np.cumsum(sizes) - sizes
        a = np.concatenate(samples)
        own = np.repeat(np.arange(q.size), sizes)
        length = s.positions[q] - s.positions[s.sensor[a[bounds]]]
        typical = travel_time(length[own], s.speed[a], s.median_speed[q][own])
        medians = run_medians(typical, sizes)
        if medians is None:
            medians = np.array([median(t) for t in np.split(typical, bounds[1:])])
        shift = PRIOR_SIDEBANDS[1] * medians
        reach = travel_time(
            np.exp(PRIOR_LOG_RANGE) * length[own], s.speed[a], s.slowest_speed[q][own]
        )
        reach += shift[own]
        earliest, latest = s.time[a] - shift[own], s.time[a] + reach
        first, count = _arrivals_within(s, q, own, (bounds, sizes), (earliest, latest))
        np.maximum(count, 0, out=count)
        lo, hi = s.start[q], s.start[q + 1]
        span_of_time = (s.sorted_time[hi - 1] - s.sorted_time[lo]).tolist()
        rates = [
            (h - lo_q - 1) / span if span > 0 else 0.0
            for lo_q, h, span in zip(lo.tolist(), hi.tolist(), span_of_time, strict=True)
        ]
        typical_sums = [
            float(np.add.reduce(typical[lo_a:hi_a]))  # each segment's own (pairwise) sum
            for lo_a, hi_a in zip(bounds.tolist(), (bounds + sizes).tolist(), strict=True)
        ]
        pa = np.repeat(a, count)
        at = (
            np.repeat(first, count)
            + np.arange(pa.size)
            - np.repeat(np.cumsum(count) - count, count)
        )
        pb = s.order[at]
        pair_of = np.repeat(own, count)
        kinematic = travel_time(length[pair_of], s.speed[pa], s.speed[pb])
        travel = s.time[pb] - s.time[pa]
        ahead = travel > 0
        values = np.log(travel[ahead] / kinematic[ahead])
        within = np.abs(values) <= PRIOR_LOG_RANGE
        return cls(
            values[within],
            pair_of[ahead][within],
            np.bincount(pair_of, minlength=q.size),
            np.bincount(pair_of[ahead], minlength=q.size) > 0,
            rates,
            typical_sums,
        )


def _arrivals_within(
    s: Sensors,
    q: IntArray,
    own: IntArray,
    runs: tuple[IntArray, IntArray],
    window: tuple[FloatArray, FloatArray],
) -> tuple[IntArray, IntArray]:
    """For each sample detection (`own`: its segment, whose far sensor is q[own]; segment k's
    are `runs` (bounds, sizes)[k]), the place in s.order of the first arrival at its far sensor
    after `window[0]`, and how many arrive from there up to `window[1]` (less than 0 where
    none): `searchsorted` in the sensor's times, right at the window's start and left at its
    end. Every segment's at once among the arrivals as (sensor, time) (`Sensors.arrival_keys`,
    as `gating._arrivals_between` finds them), where no time is NaN; else segment by segment."""
    earliest, latest = window
    keys = s.arrival_keys
    if keys is not None:
        ends = np.empty((2, own.size), dtype=np.complex128)
        ends.real = q[own]
        ends.imag[0] = earliest
        ends.imag[1] = latest
        if not np.isnan(ends.imag).any():
            first = keys.searchsorted(ends[0], side="right")
            return first, keys.searchsorted(ends[1], side="left") - first
    first, count = np.empty_like(own), np.empty_like(own)
    bounds, sizes = runs
    for qk, lo_a, hi_a in zip(q.tolist(), bounds.tolist(), (bounds + sizes).tolist(), strict=True):
        lo, hi = int(s.start[qk]), int(s.start[qk + 1])
        times = s.sorted_time[lo:hi]
        first[lo_a:hi_a] = times.searchsorted(earliest[lo_a:hi_a], side="right")
        count[lo_a:hi_a] = times.searchsorted(latest[lo_a:hi_a]) - first[lo_a:hi_a]
        first[lo_a:hi_a] += lo
    return first, count


@dataclass
class CandidatePairs:
    """Every pair (pa, pb) of a detection from sample a with a detection at sensor q that the
    segment's prior could link (up to 10x the kinematic travel time), and the pairs up to
    `shift` earlier, which only the background counts."""

    s: Sensors
    a: IntArray
    pa: IntArray
    pb: IntArray
    length: float
    shift: float  # the largest move of a travel time in the background (time units)
    rate: float  # detections per time unit at q
    typical_speed_b: float  # the median speed at q

    @classmethod
    def within_reach(cls, s: Sensors, a: IntArray, q: int) -> CandidatePairs | None:
        members = s.members(q)
        if members.size == 0 or a.size == 0:
            return None
        times = s.sorted_time[s.start[q] : s.start[q + 1]]  # s.time[members]
        length = float(s.positions[q] - s.positions[s.sensor[a[0]]])
        typical_speed_b = float(s.median_speed[q])
        typical = median(travel_time(length, s.speed[a], typical_speed_b))
        shift = PRIOR_SIDEBANDS[1] * float(typical)
        slowest = float(s.speed[members].min())
        reach = travel_time(np.exp(PRIOR_LOG_RANGE) * length, s.speed[a], slowest) + shift
        first = np.searchsorted(times, s.time[a] - shift, side="right")
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
        return cls(s, a, pa, pb, length, shift, rate, typical_speed_b)

    def log_ratios(self, keep: BoolArray) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Of the kept pairs: log(observed / kinematic travel time) of those whose travel time
        is positive and within range, and every kept pair's travel time and kinematic one."""
        s, pa, pb = self.s, self.pa[keep], self.pb[keep]
        kinematic = travel_time(self.length, s.speed[pa], s.speed[pb])
        travel = s.time[pb] - s.time[pa]
        ahead = travel > 0
        values = np.log(travel[ahead] / kinematic[ahead])
        return values[np.abs(values) <= PRIOR_LOG_RANGE], travel, kinematic

    def bias(self, keep: BoolArray) -> tuple[float, float]:
        """The most common log bias of the kept pairs, and how significant it is: as little as
        it is against either model of the unrelated pairs (`excess_over_uniform`, `excess`),
        and nothing (-inf) when the two put the bump in different places. Neither model is
        right everywhere: a uniform rate sees biases in the waves of a queue and the end of a
        batch, moved pairs in a strictly periodic flow."""
        ratios = self.log_ratios(keep)
        uniform = self.excess_over_uniform(keep, ratios[0])
        moved = self.excess(*ratios)
        centre = moved.centre()
        if abs(uniform.centre() - centre) > PRIOR_PEAK_BINS * PRIOR_BIN:
            return centre, -np.inf
        return centre, min(uniform.significance(), moved.significance())

    def excess_over_uniform(self, keep: BoolArray, values: FloatArray) -> BiasHistogram:
        """Histogram of the kept pairs' log(observed / kinematic travel time) (`values`, from
        `log_ratios`) less a background of unrelated pairs falling uniformly in time at q's
        rate, whose expected number in a bin grows as e^value (thinned as the pairs are)."""
        typical = travel_time(self.length, self.s.speed[self.a], self.typical_speed_b)
        # Thinned as the pairs are: the share kept of those ahead in time (the others are here
        # for `excess` alone).
        ahead = self.s.time[self.pb] > self.s.time[self.pa]
        thinning = float(keep[ahead].mean()) if ahead.any() else 0.0
        background = thinning * self.rate * float(typical.sum()) * PRIOR_BIN_GROWTH
        return BiasHistogram.of(values, background)

    def excess(
        self, values: FloatArray, travel: FloatArray, kinematic: FloatArray
    ) -> BiasHistogram:
        """Histogram of log(observed / kinematic travel time) of the kept pairs (`values`, from
        `log_ratios` with their `travel` and `kinematic` times) less the background of
        unrelated pairs.

        The background is the same histogram with every pair's travel time moved, in evenly
        spaced steps, by PRIOR_SIDEBANDS typical kinematic travel times either way (never by
        less, so that the true pairs' bump does not count as its own background). Unrelated
        pairs keep their shape under such moves, whatever it is: the far sensor's arrivals
        grow as a queue builds, come in waves in which the fast vehicles pass together, and
        stop where the batch ends. A uniform arrival rate, assumed instead, took the pairs of
        those shapes for biases (a stop-and-go segment got a travel time a tenth of the true
        one, and not one of its links was made)."""
        # Every pair but a stride's worth, past PRIOR_BACKGROUND_PAIRS: the background is smooth.
        stride = max(1, travel.size // PRIOR_BACKGROUND_PAIRS)
        band = np.linspace(*PRIOR_SIDEBANDS, PRIOR_SIDEBAND_STEPS) / PRIOR_SIDEBANDS[1]
        moves = self.shift * np.concatenate([-band, band])
        moved = travel[::stride][None, :] + moves[:, None]
        scale = np.broadcast_to(kinematic[::stride], moved.shape)
        ahead = moved > 0
        background = bin_counts(np.log(moved[ahead] / scale[ahead])) * (stride / moves.size)
        return BiasHistogram.of(values, background)


def bin_counts(values: FloatArray, of: IntArray | None = None, histograms: int = 1) -> FloatArray:
    """How many values fall in each of PRIOR_BINS (the last bin closed), as `np.histogram`
    counts them but for a value on an edge, which rounding may put in either bin; without its
    sort, since the bins are even. With `of`: the value's histogram among `histograms`, all
    counted at once, one after another."""
    n_bins = PRIOR_BINS.size - 1
    inside = (values >= PRIOR_BINS[0]) & (values <= PRIOR_BINS[-1])
    index = np.minimum(((values[inside] - PRIOR_BINS[0]) / PRIOR_BIN).astype(np.int64), n_bins - 1)
    if of is not None:
        index += of[inside] * n_bins
    return np.bincount(index, minlength=n_bins * histograms).astype(np.float64)


@dataclass
class BiasHistogram:
    """Pairs' log(observed / kinematic travel time): the smoothed count in each of PRIOR_BINS
    less its background (`excess`), and that count's variance."""

    values: FloatArray
    excess: FloatArray
    variance: FloatArray

    @classmethod
    def of(
        cls, values: FloatArray, background: FloatArray, counts: FloatArray | None = None
    ) -> BiasHistogram:
        """The values' histogram over PRIOR_BINS (`counts`, where already counted), less the
        background, smoothed."""
        histogram = bin_counts(values) if counts is None else counts
        return cls(
            values,
            np.convolve(histogram - background, PRIOR_SMOOTHING, mode="same"),
            np.convolve(histogram, PRIOR_SMOOTHING_SQUARED, mode="same") + PRIOR_PSEUDO_COUNT,
        )

    def significance(self) -> float:
        """How many standard deviations the highest excess stands above the kinematic
        prediction's own (bias 0)."""
        best = int(np.argmax(self.excess))
        if self.excess[best] <= 0:
            return -np.inf
        lead = self.excess[best] - self.excess[PRIOR_ZERO_BIN]
        return float(lead / np.sqrt(self.variance[best] + self.variance[PRIOR_ZERO_BIN]))

    def kinematic_stands(self) -> bool:
        """Whether a handful of targets' mode is the kinematic prediction: nothing stands above
        the background, or the kinematic bin holds a bump (PRIOR_KINEMATIC_BUMP standard
        deviations) that the highest excess does not beat by PRIOR_KINEMATIC_LEAD. Every vehicle
        of a paper-size batch starts at one place within half a minute, so unrelated pairs bunch:
        with a sensor quiet half-way through, a bump of them at 5.6 times the kinematic travel
        time outgrew the 20 true pairs, 3 standard deviations high in the kinematic bin."""
        if self.excess.max() <= 0:
            return True
        zero = PRIOR_ZERO_BIN
        own = self.excess[zero] / np.sqrt(self.variance[zero])
        return bool(own >= PRIOR_KINEMATIC_BUMP and self.significance() < PRIOR_KINEMATIC_LEAD)

    def centre(self) -> float:
        """The log bias at the highest excess: the median of the values near it."""
        best = int(self.excess.argmax())
        peak = 0.5 * (PRIOR_BINS[best] + PRIOR_BINS[best + 1])
        near = self.values[np.abs(self.values - peak) <= PRIOR_PEAK_BINS * PRIOR_BIN]
        return float(median(near)) if near.size else float(peak)
