"""Which tracks are targets: false alarms are left out, tracks the batch's window cut are kept."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.anchors import Anchors, anchor_bonus
from roadlink.association.associators.assignment.costs import Level, link_cost
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.matching import unique_inverse
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.pace import incoming_pace
from roadlink.association.associators.assignment.params import (
    LONGEST_TRAVEL_SPREADS,
    AssignmentParams,
)
from roadlink.association.associators.assignment.sensors import Sensors, arrival_keys_of
from roadlink.association.associators.assignment.tracks import (
    BoolArray,
    detection_level,
    level_terms,
)
from roadlink.association.detections import FloatArray, IntArray

# A segment's longest travel time, as its tracks took it, is this quantile of their links'.
OBSERVED_TRAVEL_QUANTILE = 0.9
# ... read where at least this many links cross it.
OBSERVED_LEAST_LINKS = 5
# Up to this many links, every segment's are sorted at once; beyond, segment by segment.
OBSERVED_AT_ONCE_LINKS = 50_000
# A sensor's surplus over its neighbour's count is a queue's where it passes this many Poisson
# deviations of that count.
STORED_DEVIATIONS = 3.0


def confirm_targets(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    track: IntArray,
    anchors: Anchors | None = None,
) -> IntArray:
    """Keep the tracks that are better explained as targets than as false alarms; number them.

    A track's evidence is what its links save over leaving their detections apart: the sum of
    (gate_cost - link cost). A few false alarms can chain up through loose, sensor-skipping
    links; their evidence stays small, a real target's does not. A track shorter than
    `min_track_length` is kept only when the batch's time window explains its shortness: the
    batch cut it off at both ends (`starts_explained`, `ends_explained`), as it does a vehicle
    that passed the first sensor in its last seconds, or a queue held it between two sensors
    (`stored_at_edges`). A track too weak to be a target is not all false alarms: inside a
    queue, links fit hardly better than chance, and a vehicle's detections end up in such
    tracks. Each of its detections is judged as a lone one instead, and kept as a target of its
    own where the window explains it (a false alarm in the middle of the batch still is not).
    Links are costed as the linking costed them, lane-order `anchors` included.
    """
    out = np.full(track.size, -1, dtype=np.int64)
    assigned = np.flatnonzero(track >= 0)
    if assigned.size == 0:
        return out
    chain = s.by_track(assigned, track)
    ids = track[chain]
    start = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    end = np.r_[start[1:], chain.size] - 1
    sizes = np.bincount(ids)
    # Links are judged by their evidence; a lone detection has none to judge, only its place.
    evidence = track_evidence(s, model, params, chain, ids, anchors)
    convincing = (evidence >= params.min_track_evidence) | (sizes == 1)
    long_enough = sizes >= params.min_track_length
    explained = _window_explains(s, model, chain, ids)
    short = ~long_enough[ids[start]]  # only these need the window to explain them
    long_enough[ids[start][short]] = explained(chain[start][short], chain[end][short])
    good = convincing & long_enough
    keep = chain[good[ids]]
    _, out[keep] = unique_inverse(track[keep])  # np.unique's, quicker on a few
    weak = chain[~convincing[ids]]
    if weak.size:
        lone = weak[explained(weak, weak)]
        out[lone] = out.max(initial=-1) + 1 + np.arange(lone.size)
    return out


def track_evidence(
    s: Sensors,
    model: SegmentModel,
    params: AssignmentParams,
    chain: IntArray,
    ids: IntArray,
    anchors: Anchors | None = None,
) -> FloatArray:
    """Per track index, the sum of what its links save over leaving their detections apart.

    `chain` holds the tracks' detections sorted by track, then sensor, and `ids` their tracks.
    Each link a -> b is costed as the forward pass saw it: against the track's mean relative
    speed up to and including a, less its anchor's bonus (`anchors.anchor_bonus`)."""
    linked = np.flatnonzero(ids[1:] == ids[:-1])
    a, b = chain[linked], chain[linked + 1]
    before = _level_before(s, chain, ids, linked)
    after = detection_level(s, b)
    if model.pace is not None:
        # Costed as the forward pass saw it: against the link into a, not yet the one out of b.
        prv = np.full(s.time.size, -1, dtype=np.int64)
        prv[b] = a
        before.pace = incoming_pace(model.pace, s, prv, a)
    pairs = Pairs.between(s, model, params, a, b)
    # An anchored link was made for its lane order (`anchors`): that is evidence too.
    cost = link_cost(params, model, pairs, before, after, s)
    if anchors is not None:  # else a bonus of 0, which changes no cost
        cost = cost - anchor_bonus(pairs, anchors)
    saving = params.gate_cost - cost
    evidence = np.bincount(ids[linked], weights=np.maximum(saving, 0.0), minlength=ids.max() + 1)
    return np.asarray(evidence, dtype=np.float64)


def _level_before(s: Sensors, chain: IntArray, ids: IntArray, linked: IntArray) -> Level:
    """The level of each track up to and including the detections chain[linked] (`chain` and
    `ids` as in `track_evidence`). Apart from it so that its arrays over every detection of
    the chain are freed before the links are costed (the confirmation's peak at 10^6)."""
    new_track = np.r_[True, ids[1:] != ids[:-1]]
    start = np.flatnonzero(new_track)
    run = np.cumsum(new_track) - 1

    def prefix_sums(values: FloatArray) -> FloatArray:
        """Sums of `values` (in chain order) from each track's start up to each detection."""
        cumulative = np.cumsum(values)
        return cumulative - np.where(start > 0, cumulative[np.maximum(start - 1, 0)], 0.0)[run]

    position = np.arange(chain.size) - start[run] + 1.0
    prefix_mean = prefix_sums(s.relative_speed[chain]) / position
    before = Level(prefix_mean[linked], position[linked])
    terms = level_terms(s)
    if len(terms) > 1:
        value, weight = terms[1]
        count = prefix_sums(weight[chain])
        before.length_count = count[linked]
        before.length_mean = prefix_sums((value * weight)[chain])[linked] / np.maximum(
            before.length_count, 1.0
        )
    return before


def _window_explains(
    s: Sensors, model: SegmentModel, chain: IntArray, ids: IntArray
) -> Callable[[IntArray, IntArray], BoolArray]:
    """Whether the batch's window explains a track from detection `first` to `last` (arrays of
    them), by the times its segments take (what the speeds predict, or what its tracks, `chain`
    and `ids` as in `track_evidence`, took: `observed_travel`, read only where the speeds
    leave a track unexplained) or by what a queue holds between its sensors
    (`stored_at_edges`)."""
    stored_first, stored_last = stored_at_edges(s)
    observed: FloatArray | None = None

    def explained(first: IntArray, last: IntArray) -> BoolArray:
        nonlocal observed
        starts = starts_explained(s, model, first) | stored_first[first]
        ends = ends_explained(s, model, last) | stored_last[last]
        if (starts & ends).all():
            return starts & ends
        if observed is None:
            observed = observed_travel(s, chain, ids)
        starts |= starts_explained(s, model, first, observed)
        ends |= ends_explained(s, model, last, observed)
        return starts & ends

    return explained


def starts_explained(
    s: Sensors, model: SegmentModel, first: IntArray, observed: FloatArray | None = None
) -> BoolArray:
    """Whether a track starting with detection `first` needs no missed detection to explain its
    start: it is at the first sensor, or the batch began too recently for its target to have
    passed the previous sensor inside it (`observed`: each segment's longest travel time as
    its tracks took it, `observed_travel`)."""
    p = s.sensor[first]
    before = np.maximum(p - 1, 0)
    longest = _longest_travel(s, model, first, before, observed)
    return (p == 0) | (s.time[first] - longest < s.time.min())


def ends_explained(
    s: Sensors, model: SegmentModel, last: IntArray, observed: FloatArray | None = None
) -> BoolArray:
    """Whether a track ending with detection `last` needs no missed detection to explain its
    end: it is at the last sensor, or the batch ended too soon for its target to reach the
    next one inside it (`observed` as in `starts_explained`)."""
    p = s.sensor[last]
    final = s.positions.size - 1
    after = np.minimum(p, max(final - 1, 0))
    longest = _longest_travel(s, model, last, after, observed)
    return (p == final) | (s.time[last] + longest > s.time.max())


def _longest_travel(
    s: Sensors, model: SegmentModel, a: IntArray, p: IntArray, observed: FloatArray | None
) -> FloatArray:
    """Longest plausible travel time of detection a's target over the segment p -> p + 1: what
    its speed predicts, or what the segment's tracks took, whichever is longer (in a queue
    vehicles take many times what their speeds at the sensors predict)."""
    gap = s.positions[np.minimum(p + 1, s.positions.size - 1)] - s.positions[p]
    spread = LONGEST_TRAVEL_SPREADS * model.time_spread[p, 1]
    predicted = gap * np.exp(model.log_bias[p, 1] + spread) / s.speed[a]
    return predicted if observed is None else np.maximum(predicted, observed[p])


def observed_travel(s: Sensors, chain: IntArray, ids: IntArray) -> FloatArray:
    """Per segment, the longest travel time its tracks took: the OBSERVED_TRAVEL_QUANTILE of
    the times of their links across it (`chain` and `ids` as in `track_evidence`), 0 where
    fewer than OBSERVED_LEAST_LINKS cross it. Inside a queue a link may be a vehicle off, but
    its time is the queue's."""
    longest = np.zeros(max(s.positions.size - 1, 1))
    linked = np.flatnonzero(ids[1:] == ids[:-1])
    a, b = chain[linked], chain[linked + 1]
    adjacent = s.sensor[b] == s.sensor[a] + 1
    a, b = a[adjacent], b[adjacent]
    counts = np.bincount(s.sensor[a], minlength=longest.size)
    read = counts >= OBSERVED_LEAST_LINKS
    if not read.any():
        return longest
    if a.size <= OBSERVED_AT_ONCE_LINKS:
        # Every segment's links sorted at once (a quantile call a segment was most of a
        # paper-size batch's confirmation).
        travel = s.time[b] - s.time[a]
        by_segment = np.lexsort((travel, s.sensor[a]))
        first = np.cumsum(counts) - counts
        longest[read] = _linear_quantile(travel[by_segment], first[read], counts[read])
        return longest
    # Segment by segment, each one's links a slice of the detections by sensor (at 10^6
    # detections a sort of every link cost seven times this).
    following = np.full(s.time.size, -1, dtype=np.int64)
    following[a] = b
    following = following[s.order]
    for p in np.flatnonzero(read).tolist():
        at = following[s.start[p] : s.start[p + 1]]
        crossed = at >= 0
        travel = s.time[at[crossed]] - s.sorted_time[s.start[p] : s.start[p + 1]][crossed]
        longest[p] = np.quantile(travel, OBSERVED_TRAVEL_QUANTILE)
    return longest


def _linear_quantile(values: FloatArray, first: IntArray, counts: IntArray) -> FloatArray:
    """OBSERVED_TRAVEL_QUANTILE of each run `values[first:first + count]` (sorted), as
    np.quantile's default (linear) method makes it."""
    at = (counts - 1) * OBSERVED_TRAVEL_QUANTILE
    below = np.floor(at).astype(np.int64)
    share = at - below
    low = values[first + below]
    high = values[first + np.minimum(below + 1, counts - 1)]
    step = high - low
    # numpy's lerp: from the nearer end, so that a share of 1 gives the upper value exactly.
    return np.where(share >= 0.5, high - step * (1 - share), low + step * share)


def stored_at_edges(s: Sensors) -> tuple[BoolArray, BoolArray]:
    """Which detections a queue explains at the batch's edges, by counts alone: vehicles are
    conserved between two sensors, so where a sensor counted more than the next, at least the
    surplus was still between them when the batch ended (its last detections, by time, in
    that number), and where it counted more than the one before, at least its surplus entered
    before the batch began (its first). A surplus counts where it passes STORED_DEVIATIONS
    Poisson deviations of the smaller count (a few false alarms or misses are no queue); a
    sensor that counted more than both neighbours has false alarms to explain rather than a
    queue, and is not explained so. The two arrays are over every detection."""
    counts = np.diff(s.start)
    first = np.zeros(s.time.size, dtype=bool)
    last = np.zeros(s.time.size, dtype=bool)
    # Segment k joins sensors k and k + 1: the upstream one's surplus is stored at the end, the
    # downstream one's entered before the start.
    near, far = counts[:-1], counts[1:]
    root = STORED_DEVIATIONS * np.sqrt(counts)
    stored_at_end = near - far >= root[1:]
    stored_at_end[1:] &= near[1:] <= counts[:-2]  # not more than the sensor before
    entered_before = far - near >= root[:-1]
    entered_before[:-1] &= far[:-1] <= counts[2:]  # nor more than the one after
    for k in np.flatnonzero(stored_at_end).tolist():
        last[s.order[s.start[k + 1] - int(near[k] - far[k]) : s.start[k + 1]]] = True
    for k in (np.flatnonzero(entered_before) + 1).tolist():
        first[s.order[s.start[k] : s.start[k] + int(counts[k] - counts[k - 1])]] = True
    return first, last


# Fewer linked detections than this share (of a batch of at least FEW_LINKS_MIN detections)
# says the detections' units are off, not the traffic.
FEW_LINKS_SHARE = 0.2
FEW_LINKS_MIN = 20
# The direction is read off at most about this many detections.
DIRECTION_SAMPLE = 5000
# Detections fit vehicles driving towards decreasing positions where the time error of their
# nearest partner at the next sensor, earlier by what their speed takes, is under this share of
# the error later (medians over the sample).
AGAINST_THE_TRAFFIC = 0.4


def few_links_warnings(s: Sensors, target: IntArray) -> tuple[str, ...]:
    """A sentence for the result where almost no detection could be linked to another (positions
    in km with speeds in m/s make every travel time a thousand times shorter than predicted,
    times in milliseconds a thousand times longer), or where the detections fit vehicles
    driving towards decreasing positions (a road numbered against the traffic: in dense traffic
    the wrong vehicles are linked, in free flow none), and the result would otherwise only say
    that every detection stands alone, or nothing."""
    if target.size < FEW_LINKS_MIN:
        return ()
    if _against_the_traffic(s):
        return (
            "the detections fit vehicles driving towards decreasing positions far better than "
            "towards increasing ones: positions must grow in the direction of travel (a road "
            "numbered against the traffic links the wrong vehicles, or none)",
        )
    sizes = np.bincount(target[target >= 0])
    linked = float(sizes[sizes >= 2].sum()) / target.size
    if linked >= FEW_LINKS_SHARE:
        return ()
    return (
        f"only {linked:.0%} of the detections could be linked to another: check that positions, "
        "timestamps and speeds are in matching units (speeds in m/s over positions in km, or "
        "times in milliseconds, fit no vehicle)",
    )


def _against_the_traffic(s: Sensors) -> bool:
    """Whether the detections fit vehicles driving towards decreasing positions far better than
    towards increasing ones: for a sample of detections (every sensor's but the last), the time
    error, over the time their speed takes across the gap, of the nearest detection at the next
    sensor that much later, and that much earlier; the earlier must be under
    AGAINST_THE_TRAFFIC of the later (medians). Where speeds tell travel times (free flow,
    dense traffic) the true direction's errors are a few per cent and the other's a quarter of a
    headway or more (SUMO's dense traffic: 0.8 against 2.9 %); in a queue the two are alike,
    and nothing is said. Every run asks, so one search for the whole sample, each way."""
    keys = s.arrival_keys
    if keys is None or s.positions.size < 2:
        return False
    a = s.order[: s.start[-2]]
    a = a[:: max(1, a.size // DIRECTION_SAMPLE)]
    if a.size < FEW_LINKS_MIN:
        return False
    nxt = s.sensor[a] + 1
    gap = (s.positions[nxt] - s.positions[s.sensor[a]]) / s.speed[a]
    later, earlier = (_nearest_error(keys, nxt, s.time[a] + sign * gap) / gap for sign in (1, -1))
    return bool(np.median(earlier) < AGAINST_THE_TRAFFIC * np.median(later))


def _nearest_error(
    keys: npt.NDArray[np.complex128], sensor: IntArray, time: FloatArray
) -> FloatArray:
    """How far each `time` lies from the nearest arrival at its `sensor` (inf: none there), among
    the arrivals as (sensor, time) (`Sensors.arrival_keys`)."""
    at = keys.searchsorted(arrival_keys_of(sensor, time))
    error = np.full(time.size, np.inf)
    for j in (np.maximum(at - 1, 0), np.minimum(at, keys.size - 1)):
        there = keys.real[j] == sensor
        error[there] = np.minimum(error[there], np.abs(keys.imag[j][there] - time[there]))
    return error


# A sensor is named as noisy where at least NOISY_MIN of its reports, and NOISY_SHARE of them,
# joined no vehicle, and it reported more than the busier of its neighbours by at least
# NOISY_EXCESS of those (and by 3 Poisson deviations of that neighbour's count).
NOISY_MIN = 10
NOISY_SHARE = 0.15
NOISY_EXCESS = 0.5


def noisy_sensor_warnings(s: Sensors, target: IntArray) -> tuple[str, ...]:
    """A sentence for each sensor that reported more vehicles than either neighbour, the extra
    reports linked to nothing: false alarms (a noisy or double-triggering detector). Its false
    alarms stay unassigned and cost the road little; whoever keeps the detector should know.

    Both neighbours must have seen fewer: vehicles stored in a queue between two sensors leave
    the upstream one with more reports and many unlinked, but never more than the sensor
    before it. On SUMO traffic a sensor with half again its reports as false alarms is named
    (free flow, dense, irregular spacing, faulty loops; not inside a queue, where false alarms
    are linked into the crawl), and none of 270 exported cases has one named."""
    counts = np.diff(s.start).astype(np.float64)
    if counts.size < 3:
        return ()
    assigned = target >= 0
    unlinked = counts - np.bincount(s.sensor[assigned], minlength=counts.size)
    busier = np.maximum(counts[:-2], counts[2:])
    excess = counts[1:-1] - busier
    inner = unlinked[1:-1]
    noisy = (
        (inner >= NOISY_MIN)
        & (inner >= NOISY_SHARE * counts[1:-1])
        & (excess >= NOISY_EXCESS * inner)
        & (excess >= 3.0 * np.sqrt(busier))
    )
    return tuple(
        f"the sensor at position {s.positions[k]:g} reported {counts[k] / busier[k - 1]:.1f} "
        f"times as many detections as the busier of its neighbours, and {unlinked[k]:.0f} of "
        f"them ({unlinked[k] / counts[k]:.0%}) joined no vehicle: false alarms (a noisy or "
        "double-triggering detector?)"
        for k in (np.flatnonzero(noisy) + 1).tolist()
    )
