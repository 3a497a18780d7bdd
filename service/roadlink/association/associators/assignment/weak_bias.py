"""A segment's prior bias that the pairs' histogram shows too weakly to stand on its own,
checked by matching the detections under it, and kept where a sensor's clock or its speeds'
calibration explains it.

The prior (`prior.travel_time_bumps`) keeps the kinematic prediction unless another bias holds
clearly more pairs than the kinematic prediction's own bin, since in a queue the highest bump is
often chance. But where the true bias is moderate and traffic dense, that bin is full of pairs
of a vehicle with the one ahead of or behind its true partner, and the true bump misses the
test: a sensor whose clock runs 2 s late (SUMO's dense motorway, sensors 250 m apart) put it at
4.0 standard deviations against the 5 required. From the kinematic start the learning then
locked onto links shifted by a vehicle, which explain each other as well as the true ones, and
4 % of the segment's links were right. Matching tells the two apart where the histogram cannot:
under the true bias each detection finds a partner whose travel time *and* speed fit, under a
wrong one it pairs with a neighbour whose speed differs. So a weaker bump's bias is kept when
matching the sample's detections under it costs less than under the kinematic prediction.

Only detections whose partner falls inside the batch's time window under both biases are
matched: in a crawl half the detections have no partner in the window, and a bias that pairs
them with vehicles that are there would win for that alone.

A sensor whose speeds read some factor off (a single loop's assumed vehicle length) moves both
its segments' biases alike, and where its factor is moderate and traffic dense neither bump
stands out nor does matching confirm either alone. Its median speed stands off its neighbours'
by that factor, though, which says where to look: the biases that factor gives both segments are
matched, and kept where both save a fainter FAINT_BIAS_SAVING a detection (`calibration_biases`).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.matching import matched_cost
from roadlink.association.associators.assignment.params import FLOWING_SHARE
from roadlink.association.associators.assignment.sensors import travel_time

# What matching under a weaker bump's bias must save a sampled detection, against the kinematic
# prediction (a squared error of one spread): a bump one headway off the true bias, the queue's
# shifted alignment, fits its pairs about as well as the truth (a synthetic wave: 0.5-0.6 a
# detection), a true bias 1.3-2.3 (a sensor's clock 2 s late in dense traffic, slow zones).
WEAK_BIAS_SAVING = 1.0
# The biases tried around the bump (log travel time): a bin's width either side, and then some.
WEAK_BIAS_REACH = 0.1
WEAK_BIAS_STEPS = 11
# A sensor whose median speed stands this factor or more off its neighbours' is tested for a
# speed calibration off by it (`calibration_biases`): its segments' biases as that factor would
# make them are taken where matching confirms both by FAINT_BIAS_SAVING a detection or more (short
# of WEAK_BIAS_SAVING, which one segment's weak bias needs alone). In dense traffic a sensor
# reading 0.7 times the speed left both its segments' biases (-0.19) at 0.45-0.91 a detection on
# three seeds of five, below the histogram's significance, and the first tracks broke there.
CALIBRATION_LEAST = 1.1
FAINT_BIAS_SAVING = 0.4
# A neighbouring segment mirrors a weak bias where its shift in seconds is the opposite of the
# weak one's within this factor (a clock 2 s late: +1.7 s into the sensor, -1.9 s out of it).
CLOCK_MIRROR = 1.5
# A neighbouring segment echoes a weak bias where its log bias has the same sign and is within
# this factor of it: a sensor that reads speeds k times too high shortens the kinematic
# prediction of both its segments by the same factor, 1 / ((1 + 1 / k) / 2), and the other
# ends' sensors' own calibration moves each by its own (10 % per sensor, lognormal: 1.2-1.8x).
SCALE_ECHO = 2.0
# A sensor whose speeds its segments' biases put this factor off or more, either way, is named in
# a warning (where its median speed stands off its neighbours' too). On 203 exported SUMO cases
# with exact speeds none is; per-sensor calibration errors of 8-10 % name one in 3 cases of 20.
SPEED_FACTOR_WARNING = 1.25

if TYPE_CHECKING:
    from roadlink.association.associators.assignment.params import AssignmentParams
    from roadlink.association.associators.assignment.prior import CandidatePairs
    from roadlink.association.detections import FloatArray


def confirmed_bias(
    pairs: CandidatePairs, bump: float, params: AssignmentParams
) -> tuple[float, float] | None:
    """The bias near `bump` (within `WEAK_BIAS_REACH`) under which the sample's detections
    match the far sensor's at least cost, and what it saves a sampled detection against the
    kinematic prediction (bias 0), where that is at least `FAINT_BIAS_SAVING`; else None. (At
    `WEAK_BIAS_SAVING` or more it is confirmed alone.) Each pair costs its travel time's and
    its speed change's squared errors at the prior's spreads, each detection left alone half
    the gate. (The histogram's bump is a bin's centre among pairs that are mostly unrelated;
    the matching's best bias is the true pairs' own: on a slow zone -0.28 to -0.30 where the
    bump said -0.32 to -0.37, the true links -0.29 to -0.31.)"""
    s = pairs.s
    near, far = int(s.sensor[pairs.a[0]]), int(s.sensor[pairs.pb[0]])
    biases = bump + np.linspace(-WEAK_BIAS_REACH, WEAK_BIAS_REACH, WEAK_BIAS_STEPS)
    travel = s.time[pairs.pb] - s.time[pairs.pa]
    kinematic = travel_time(pairs.length, s.speed[pairs.pa], s.speed[pairs.pb])
    keep = travel > 0
    keep[keep] &= _inside_under(pairs, near, far, (0.0, float(biases[0]), float(biases[-1])))[keep]
    pa, pb = pairs.pa[keep], pairs.pb[keep]
    if pa.size == 0:
        return None
    error = np.log(travel[keep] / kinematic[keep])
    change = s.relative_speed[pb] - s.relative_speed[pa]
    speed_cost = np.square(change / params.velocity_change_spread)

    def cost_at(centre: float) -> float:
        cost = np.square((error - centre) / params.travel_time_spread) + speed_cost
        return matched_cost(pa, pb, cost, params.gate_cost)

    costs = [cost_at(float(bias)) for bias in biases]
    best = int(np.argmin(costs))
    saving = (cost_at(0.0) - costs[best]) / pairs.a.size
    if saving < FAINT_BIAS_SAVING:
        return None
    return float(biases[best]), saving


def _inside_under(
    pairs: CandidatePairs, near: int, far: int, biases: tuple[float, ...]
) -> np.ndarray:
    """Of every pair, whether both its detections would find their partner inside the batch's
    time window under each of `biases`: its near detection's arrival at the far sensor, at its
    own speed and the far sensor's typical one, and its far detection's passage of the near
    sensor, likewise."""
    s = pairs.s
    near_times = s.sorted_time[s.start[near] : s.start[near + 1]]
    far_times = s.sorted_time[s.start[far] : s.start[far + 1]]
    ahead: FloatArray = travel_time(pairs.length, s.speed[pairs.pa], s.median_speed[far])
    behind: FloatArray = travel_time(pairs.length, s.median_speed[near], s.speed[pairs.pb])
    inside = np.ones(pairs.pa.size, dtype=bool)
    for bias in biases:
        arrival = s.time[pairs.pa] + ahead * np.exp(bias)
        passage = s.time[pairs.pb] - behind * np.exp(bias)
        inside &= (arrival >= far_times[0]) & (arrival <= far_times[-1])
        inside &= (passage >= near_times[0]) & (passage <= near_times[-1])
    return inside


def clock_shifts(
    weak: dict[int, float], biases: FloatArray, seconds: FloatArray
) -> dict[int, float]:
    """Of the confirmed weak biases `weak` (by segment), those that a neighbouring segment's
    bias (`biases`, or its own weak one) mirrors: about the same seconds the other way, within
    `CLOCK_MIRROR` of each other, at typical travel times of `seconds`. That is what a sensor
    whose clock runs early or late does to the segments either side of it. Elsewhere the
    learning finds a weak bias from the kinematic start as well or better: on a slow zone
    (SUMO, five seeds, no lanes or lengths) starting from the confirmed biases, true to 0.02,
    scored 84.0 % against 85.4 % from the kinematic prediction."""
    shift = {p: float(seconds[p] * np.expm1(bias)) for p, bias in weak.items()}
    kept: dict[int, float] = {}
    for p, bias in weak.items():
        for q in (p - 1, p + 1):
            if not 0 <= q < seconds.size:
                continue
            other = shift.get(q, float(seconds[q] * np.expm1(biases[q])))
            ratio = -other / shift[p] if shift[p] != 0 else 0.0
            if 1 / CLOCK_MIRROR <= ratio <= CLOCK_MIRROR:
                kept[p] = bias
    return kept


def scale_echoes(weak: dict[int, float], biases: FloatArray) -> dict[int, float]:
    """Of the confirmed weak biases `weak` (by segment), those that a neighbouring segment's
    bias (`biases`, or its own weak one) echoes: the same sign, within `SCALE_ECHO` of it.
    That is what a sensor whose speeds read some factor off (a loop's calibration, a sensor
    set to km/h among sensors in m/s) does to the segments either side of it: the kinematic
    prediction of both is off by about that factor's half, the same way. Left alone, the
    learning locked onto links shifted by a vehicle (SUMO's dense motorway, one sensor in km/h:
    the segment after it 0 % right, 66 % of the vehicles; every sensor's speeds off by a
    lognormal 10 %: 0 % on the segment whose ends both read 20 % high). A slow zone's or a
    traffic light's weak bias has no such echo (their neighbours keep the kinematic
    prediction), and kept there it cost 1 to 1.4 points."""
    return {
        p: bias
        for p, bias in weak.items()
        if any(
            echo(weak.get(q, float(biases[q])), bias)
            for q in (p - 1, p + 1)
            if 0 <= q < biases.size
        )
    }


def explained_biases(
    confirmed: dict[int, tuple[float, float]],
    log_bias: FloatArray,
    seconds: FloatArray,
    median_speed: FloatArray,
    pairs_of: Callable[[int], CandidatePairs | None],
    params: AssignmentParams,
) -> dict[int, float]:
    """The segments' weak biases (by segment) that a sensor's clock or its speeds' calibration
    explains: those matching confirmed (`confirmed`: by segment, the bias and its saving a
    detection; WEAK_BIAS_SAVING or more) that a neighbour mirrors (`clock_shifts`) or echoes
    (`scale_echoes`), and the pairs a sensor's calibration gives (`calibration_biases`). The
    segments' prior biases are `log_bias`, their typical travel times `seconds`, each sensor's
    median speed `median_speed`, and each segment's sampled pairs `pairs_of(segment)` (None
    where they are no test of a sensor's calibration), matched at `params`' spreads."""
    weak = {p: bias for p, (bias, saving) in confirmed.items() if saving >= WEAK_BIAS_SAVING}
    explained = clock_shifts(weak, log_bias, seconds)
    explained.update(scale_echoes(weak, log_bias))
    explained.update(calibration_biases(confirmed, log_bias, median_speed, pairs_of, params))
    return explained


def calibration_biases(
    confirmed: dict[int, tuple[float, float]],
    log_bias: FloatArray,
    median_speed: FloatArray,
    pairs_of: Callable[[int], CandidatePairs | None],
    params: AssignmentParams,
) -> dict[int, float]:
    """The segments' biases where a sensor's speeds read some factor off (a loop's calibration):
    for each sensor between two segments whose histograms left the kinematic prediction standing
    (`log_bias` 0), where its median speed stands at least CALIBRATION_LEAST off its
    neighbours' (of `median_speed`, by sensor; NaN where a sensor's speeds tell nothing of its
    calibration), the biases that factor would give both segments
    (`calibration_bias`), each matched near it (`confirmed_bias` of the segment's pairs,
    `pairs_of(segment)`, unless `confirmed` has it already: by segment, the bias and its
    saving a detection) and kept where both save at least FAINT_BIAS_SAVING a detection, echo
    each other and put the factor as the median speed does (`off_as_factor`), where traffic
    flows at the sensor and both neighbours (`params.FLOWING_SHARE`). Traffic slower at a sensor
    takes longer over its segments too, and leaves the kinematic prediction the better match
    there; a queue's alignment shifted by a vehicle moves each segment its own way, but at a
    queue's head or tail both may move alike (SUMO's queue: a sensor among crawling neighbours
    taken to read 1.6 times the speed, 1 point lost, before traffic had to flow there).

    The first and the last sensor have one segment and nothing to echo: its bias is kept where
    matching confirms it as above, at the factor the sensor's median speed stands off its one
    neighbour's, where the neighbour's other segment keeps the kinematic prediction too (else
    the neighbour may be the sensor off) and traffic flows at the three sensors of the road's end
    (`road_ends`).
    """
    kept: dict[int, float] = {}
    told = median_speed[np.isfinite(median_speed)]
    flowing = median_speed >= FLOWING_SHARE * (told.max() if told.size else np.inf)
    for k in range(1, median_speed.size - 1):
        factor = median_speed[k] / np.sqrt(median_speed[k - 1] * median_speed[k + 1])
        if not abs(np.log(factor)) >= np.log(CALIBRATION_LEAST) or log_bias[k - 1] or log_bias[k]:
            continue  # (NaN, a sensor whose speeds tell nothing, is never off)
        if not flowing[k - 1 : k + 2].all():
            continue
        predicted = calibration_bias(factor)
        into = confirmed.get(k - 1) or _confirmed_near(pairs_of(k - 1), predicted, params)
        out_of = confirmed.get(k) or _confirmed_near(pairs_of(k), predicted, params)
        if into is None or out_of is None or not echo(into[0], out_of[0]):
            continue
        factor = float(speed_factors(np.array([into[0], out_of[0]]))[1])
        if off_as_factor(median_speed[k - 1 : k + 2], factor):
            kept[k - 1], kept[k] = into[0], out_of[0]
    n = median_speed.size
    ends = road_ends(n)
    for k, segment, beside, other in ((0, 0, 1, 1), (n - 1, n - 2, n - 2, n - 3)):
        if n < 3 or segment in kept or other in kept or log_bias[segment] or log_bias[other]:
            continue
        factor = median_speed[k] / median_speed[beside]
        if not abs(np.log(factor)) >= np.log(CALIBRATION_LEAST) or not flowing[ends[k]].all():
            continue
        predicted = calibration_bias(factor)
        found = confirmed.get(segment) or _confirmed_near(pairs_of(segment), predicted, params)
        if found is not None and found[1] >= FAINT_BIAS_SAVING and echo(found[0], predicted):
            kept[segment] = found[0]
    return kept


def calibration_bias(factor: float) -> float:
    """The log bias of both segments of a sensor reading `factor` times the speed, at its speed
    and its neighbour's alike: its kinematic prediction is (1 + 1 / factor) / 2 times the true."""
    return -math.log((1.0 + 1.0 / factor) / 2.0)


def factor_of_bias(bias: npt.ArrayLike) -> FloatArray:
    """The speed factor that `calibration_bias` turns into `bias`, elementwise; 1 where none
    does (a bias of log 2 or more: no factor lengthens a prediction to half)."""
    half = 2.0 * np.exp(-np.asarray(bias, dtype=np.float64)) - 1.0
    factor: FloatArray = np.where(half > 0, 1.0 / np.where(half > 0, half, 1.0), 1.0)
    return factor


def road_ends(n: int) -> dict[int, list[int]]:
    """The first and the last of n sensors (n >= 3), each with the two sensors beside it in
    road order: where traffic must flow for its calibration to be read off its one segment."""
    return {0: [0, 1, 2], n - 1: [n - 1, n - 2, n - 3]}


def _confirmed_near(
    pairs: CandidatePairs | None, bias: float, params: AssignmentParams
) -> tuple[float, float] | None:
    """`confirmed_bias` of `pairs` near `bias` (None for no pairs)."""
    return None if pairs is None else confirmed_bias(pairs, bias, params)


def off_as_factor(medians: FloatArray, factor: float) -> bool:
    """Whether the middle of three sensors' median speeds (`medians`, in road order) stands off
    the other two's (their geometric mean) the way a speed `factor` at it would put it, by at
    least half that factor (in log)."""
    between = float(np.log(medians[1] / np.sqrt(medians[0] * medians[2])))
    return factor != 1.0 and between * math.log(factor) >= 0.5 * math.log(factor) ** 2


def echo(a: npt.ArrayLike, b: npt.ArrayLike) -> npt.NDArray[np.bool_]:
    """Whether log biases `a` and `b` echo each other: the same sign, each within `SCALE_ECHO`
    of the other (elementwise)."""
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    return (
        (a * b > 0) & (np.abs(a) <= SCALE_ECHO * np.abs(b)) & (np.abs(b) <= SCALE_ECHO * np.abs(a))
    )


def speed_factors(log_bias: FloatArray) -> FloatArray:
    """Each sensor's speed factor as its two segments' prior biases (`log_bias`, by segment)
    say it where they echo each other (1 where they do not, and at the road's ends): a sensor
    reading k times the speed makes both its segments' log bias -log((1 + 1 / k) / 2), so k =
    1 / (2 e^-b - 1) at their mean b."""
    factor = np.ones(log_bias.size + 1)
    into, out_of = log_bias[:-1], log_bias[1:]
    factor[1:-1] = np.where(echo(into, out_of), factor_of_bias(0.5 * (into + out_of)), 1.0)
    return factor


def speed_factor_warnings(
    positions: FloatArray, log_bias: FloatArray, median_speed: FloatArray
) -> list[str]:
    """A sentence for each sensor whose speeds read `SPEED_FACTOR_WARNING` or more off what the
    travel times either side of it give, for whoever keeps the detector (its calibration or
    unit; the association takes the factor into its segments' biases), where its median speed
    stands off its neighbours' the same way, by at least half that factor (in log): in a queue
    two segments' travel times may both run long while the sensor between them reads what its
    neighbours read (an oracle's true biases in a lane drop's queue gave 2.0). The first and
    the last sensor are read off their one segment's bias, where the neighbour's other segment
    keeps the kinematic prediction, traffic flows at the three sensors of the road's end and
    the median speed stands off the one neighbour's alike (traffic slower there, not a
    calibration, makes the bias the other sign; a queue's entry, read against the traffic, took
    its first segment's bias of 0.16 for a sensor reading 1.43 times the speed)."""
    factor = speed_factors(log_bias)
    n = factor.size
    if n >= 3:
        flowing = median_speed >= FLOWING_SHARE * median_speed.max()
        for k, segment, other in ((0, 0, 1), (n - 1, n - 2, n - 3)):
            read = log_bias[other] == 0.0 and flowing[road_ends(n)[k]].all()
            factor[k] = float(factor_of_bias(log_bias[segment])) if read else 1.0
    off = np.abs(np.log(factor)) >= np.log(SPEED_FACTOR_WARNING)
    for k in np.flatnonzero(off).tolist():
        if 0 < k < n - 1:
            off[k] = off_as_factor(median_speed[k - 1 : k + 2], float(factor[k]))
        else:
            beside = float(median_speed[1 if k == 0 else n - 2])
            off[k] = off_as_factor(np.array([beside, median_speed[k], beside]), float(factor[k]))
    return [
        f"the sensor at position {positions[k]:g} reads speeds about {factor[k]:.2f} times what "
        f"the travel times {'either side of it' if 0 < k < n - 1 else 'to the sensor next to it'} "
        "give: its speed calibration or unit is off (km/h read as m/s is 3.6 times); the "
        "association allowed for it"
        for k in np.flatnonzero(off).tolist()
    ]
