"""Learning each segment's behaviour from the confident tracks' links (the EM's M step).

Centres are medians and spreads 1.4826 x MAD (robust to the odd wrong link); each segment's
spreads are shrunk towards those pooled over all segments, and its centres towards the prior's.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from roadlink.association.associators.assignment.anchors import Anchors
from roadlink.association.associators.assignment.duplicates import join_duplicates
from roadlink.association.associators.assignment.edges import WindowEdges
from roadlink.association.associators.assignment.ends import RoadEnds, learn_road_ends, readable
from roadlink.association.associators.assignment.features import learn_features
from roadlink.association.associators.assignment.gating import Pairs
from roadlink.association.associators.assignment.model import SegmentModel, Tails
from roadlink.association.associators.assignment.pace import learn_pace
from roadlink.association.associators.assignment.params import (
    CONFIDENT_TRACK_LENGTH,
    MIN_RELATIVE_SPREAD,
    SKEW_MIN_LINKS,
    SKEW_SAMPLE,
    SKEW_SIGNIFICANCE,
    SKEW_STEPS,
    TAIL_SAMPLE,
    AssignmentParams,
)
from roadlink.association.associators.assignment.robust import (
    MAD_TO_STD,
    SHORT_ARRAY,
    column_medians,
    median,
    run_medians,
    runs,
    spread,
)
from roadlink.association.associators.assignment.sensors import (
    KINEMATIC_SKEW,
    Sensors,
    travel_time,
)
from roadlink.association.detections import FloatArray, IntArray

SKEW_GRID = np.linspace(0.0, 1.0, SKEW_STEPS + 1)

Links = tuple[IntArray, IntArray]


# Links above which `learn_segments` learns span by span (see there).
SPANS_AT_ONCE_LINKS = 1 << 16


def learn_segments(
    s: Sensors,
    track: IntArray,
    params: AssignmentParams,
    prior: SegmentModel,
    anchor: Anchors | None = None,
) -> SegmentModel:
    """Fit every segment's model, span by span, from the links of the confident tracks (and the
    links that lane order `anchor`s, `confident_detections`); then the spread of a track's speed
    about its own pace, and the tails of the residuals."""
    model = prior.copy()
    confident = confident_detections(track, anchor)
    # Detections of a track in road order: sort by (track, sensor).
    chain = s.by_track(confident, track)
    links: list[Links] = []
    spans = []
    for span in range(1, model.max_span + 1):
        a, b = span_links(s, track, chain, span)
        if a.size < params.min_segment_samples:
            continue  # keep the prior for this span
        links.append((a, b))
        spans.append(span)
    # Every span's segments at once where the links are few (a paper-size batch paid numpy's
    # fixed costs span after span); span by span where they are many, so that only one span's
    # links and their residuals are held at once: at 10^6 detections all spans' at once doubled
    # the association's peak memory. The same numbers either way (`learn_spans`).
    if sum(a.size for a, _ in links) <= SPANS_AT_ONCE_LINKS:
        learn_spans(s, params, model, spans, links)
    else:
        for span, span_pairs in zip(spans, links, strict=True):
            learn_spans(s, params, model, [span], [span_pairs])
    deviation = pace_deviations(s, track, confident)
    if deviation.size:
        model.preferred_speed_spread = spread(deviation)
    model.preferred_speed_spread = max(model.preferred_speed_spread, MIN_RELATIVE_SPREAD)
    np.maximum(model.time_spread, MIN_RELATIVE_SPREAD, out=model.time_spread)
    np.maximum(model.speed_spread, MIN_RELATIVE_SPREAD, out=model.speed_spread)
    learn_tails(s, params, model, links, deviation)
    keep_sparse_segments(s, model, prior)
    prv = np.full(s.time.size, -1, dtype=np.int64)
    same = track[chain[1:]] == track[chain[:-1]]
    prv[chain[1:][same]] = chain[:-1][same]
    model.pace = learn_pace(s, params, model, links, prv)
    if s.features is not None and prior.features is not None:
        model.features = learn_features(s.features, s.sensor, prior.features, links)
    return model


def keep_sparse_segments(s: Sensors, model: SegmentModel, prior: SegmentModel) -> None:
    """Every span that starts, ends or passes at a sparse sensor (one that stopped reporting
    early in a busy batch, `Sensors.sparse`) keeps the prior's travel time. A segment into or
    out of it has few links, all near the window's edge, where a detection's partner may lie
    outside it and the matching takes a neighbour's instead, at a travel time too short: learned
    from them, a segment took a travel time 17-20 % short and the next rounds built it (SUMO's
    dense traffic, a sensor quiet after its first 10 or 25 detections: 81 and 83 % right, 94 and
    93.6 % keeping the prior, 94-95 % with that sensor's detections removed). The links over
    it are many, but the first round makes them at the prior's loose spread, among vehicles a
    headway apart: on SUMO's junctions and dense traffic with the middle sensor keeping 10
    reports, they taught their span a travel time 8 % short (the true ones scatter by 0.8 %),
    and 67-71 % of the vehicles were right; keeping the prior's, whose typical speed at the
    sparse sensor is its neighbours' (`Sensors.typical_speed`), 85-87 %."""
    sparse = s.sparse
    if not sparse.any():
        return
    # Sparse sensors among 0 .. p: reached[p + 1]; a span from p over k sensors holds one
    # where reached[p + k + 1] > reached[p].
    reached = np.r_[0, np.cumsum(sparse)]
    n = sparse.size
    for span in range(1, model.max_span + 1):
        p = np.arange(max(n - span, 0))
        touching = reached[p + span + 1] > reached[p]
        model.log_bias[p[touching], span] = prior.log_bias[p[touching], span]


def learn_ends(
    s: Sensors, track: IntArray, model: SegmentModel, leader: IntArray
) -> RoadEnds | None:
    """Where vehicles leave or join the road (`ends.learn_road_ends`), from the `track`s, each
    detection near the batch's window read with `model`'s travel times, the copies that join
    their twins' targets (`leader`: `duplicates.duplicate_followers`) not counted."""
    if not readable(s):
        return None
    window = WindowEdges.of(s, replace(model, ends=None), 1.0)
    copies = (track < 0) & (join_duplicates(track, leader) >= 0)
    return learn_road_ends(s, track, window.leaving, window.arriving, copies)


def confident_detections(track: IntArray, anchor: Anchors | None = None) -> IntArray:
    """The detections of tracks with at least CONFIDENT_TRACK_LENGTH detections, and of tracks
    that hold a link lane order anchors (one that weighs, `anchors.weigh_anchors`).

    A track of one link may be two vehicles paired by chance; one of several links has held
    together over several segments. But in a crawl, where a segment takes minutes of a batch of
    five, no vehicle is seen at three sensors: the tracks that are are those whose links were
    made too fast, and learning from them alone taught each segment their travel times. An
    anchored link is sure on other grounds (its lane's order), so its track counts however short."""
    assigned = np.flatnonzero(track >= 0)
    sizes = np.bincount(track[assigned])
    sure = sizes >= CONFIDENT_TRACK_LENGTH
    if anchor is not None:
        b = np.flatnonzero(anchor.bonus > 0)
        a = anchor.predecessor[b]
        sure[track[b[(track[b] >= 0) & (track[a] == track[b])]]] = True
    return assigned[sure[track[assigned]]]


def span_links(s: Sensors, track: IntArray, chain: IntArray, span: int) -> Links:
    """The links a -> b of the tracks in `chain` (detections sorted by track, then sensor) that
    span exactly `span` sensors forwards in time."""
    if chain.size <= span:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    a, b = chain[:-span], chain[span:]
    same = track[a] == track[b]
    a, b = a[same], b[same]
    within = s.sensor[b] - s.sensor[a] == span
    a, b = a[within], b[within]
    forwards = s.time[b] - s.time[a] > 0
    return a[forwards], b[forwards]


def learn_spans(
    s: Sensors,
    params: AssignmentParams,
    model: SegmentModel,
    spans: list[int],
    links: list[Links],
) -> None:
    """Every segment's skew, bias, speed ratio and their spreads over each of `spans` sensors,
    from that span's links a -> b, into `model`. A segment's weight grows with its number of
    links: a segment seen by ten targets must not get a spread measured on ten numbers alone.

    A segment is a span and its first sensor (`key`, span by span): each segment's numbers come
    from its own links alone, so every span's segments are learned at once, their medians by
    one `robust.run_medians` call where the runs are short (a paper-size batch paid numpy's
    fixed costs span after span), the same numbers as span by span."""
    if not spans:
        return
    n_sensors = s.positions.size
    # One span (a large batch's, `learn_segments`): its own arrays, not a copy.
    a, b = links[0]
    if len(links) > 1:
        a, b = np.concatenate([a for a, _ in links]), np.concatenate([b for _, b in links])
    row = np.repeat(np.arange(len(spans)), [a.size for a, _ in links])
    key = row * n_sensors + s.sensor[a]
    counts = np.bincount(key, minlength=len(spans) * n_sensors)
    weight = counts / (counts + params.min_segment_samples)
    segment = runs(key, counts)
    seen = np.flatnonzero(counts)
    segments = Segments(np.array(spans), row, key, counts, weight, segment, seen)
    log_bias = learn_skews_and_biases(s, model, segments, (a, b))
    ratio = s.log_speed[b] - s.log_speed[a]
    learn_centres_and_spreads(params, model, segments, log_bias, ratio)


def learn_skews_and_biases(
    s: Sensors, model: SegmentModel, g: Segments, links: Links
) -> FloatArray:
    """Each segment's skew, into `model`, and each link's log travel-time bias under it.

    Apart from `learn_spans` so that the links' travel times, gaps and speeds are freed before
    the centres and spreads are learned (at 10^6 detections a span's links are a million, and
    each such array 7.6 MiB)."""
    a, b = links
    n_sensors = s.positions.size
    dt = s.time[b] - s.time[a]
    # Every link of a segment spans its gap (`span_links` keeps exactly `span` sensors): one
    # gap a segment, gathered by key, instead of each far end's sensor and position.
    first = np.arange(n_sensors)
    far = np.minimum(first + g.spans[:, None], n_sensors - 1)
    dx = (s.positions[far] - s.positions[first]).reshape(-1)[g.key]
    skew = np.full(g.counts.size, KINEMATIC_SKEW)
    # An even sample of each segment's links, taken before the gathers.
    here = [g.links[k][:: max(1, g.links[k].size // SKEW_SAMPLE)] for k in g.seen]
    speed_a, speed_b = s.speed[a], s.speed[b]  # gathered once for the skews and the biases
    learned = best_skews(dt, dx, speed_a, speed_b, here)
    skew[g.seen] = KINEMATIC_SKEW + g.weight[g.seen] * (learned - KINEMATIC_SKEW)
    model.skew[:, g.spans] = skew.reshape(g.spans.size, n_sensors).T
    log_bias: FloatArray = np.log(dt / travel_time(dx, speed_a, speed_b, skew[g.key]))
    return log_bias


@dataclass(frozen=True)
class Segments:
    """The segments of `learn_spans`: segment k is span `spans[k // n_sensors]` from sensor
    `k % n_sensors`; each link's span (its row in `spans`) and segment, each segment's number
    of links, weight and links (`robust.runs`), and the segments that have links."""

    spans: IntArray
    row: IntArray
    key: IntArray
    counts: IntArray
    weight: FloatArray
    links: list[IntArray]
    seen: IntArray


def learn_centres_and_spreads(
    params: AssignmentParams,
    model: SegmentModel,
    g: Segments,
    log_bias: FloatArray,
    ratio: FloatArray,
) -> None:
    """Each segment's log bias and log speed ratio, and their spreads: the spreads shrunk
    towards those pooled over the span's segments by `weight`, the centres towards the prior's
    by precision (the prior is a rough guess, so a handful of links overrule it). The two
    residuals are used up: worked out in place (their deviations, then the absolute ones), as
    a copy of each, twice, was a quarter of learning's memory at 10^6 detections."""
    n_segments, n_spans = g.counts.size, g.spans.size
    n_sensors = n_segments // n_spans
    seen = g.seen
    # The two residuals as two arrays, not one of both: at 10^6 detections one of both is 46 MB,
    # beyond what the allocator keeps for reuse (32 MB), so each was fresh memory from the
    # kernel, and its page faults cost as much as the arithmetic.
    residuals = (log_bias, ratio)
    centre = np.zeros((n_segments, 2))
    centre[seen] = segment_medians(residuals, g.links, seen)
    for j, residual in enumerate(residuals):
        np.subtract(residual, centre[:, j][g.key], out=residual)
    about = residuals
    # Spreads pooled over a span's segments, each residual taken from its own segment's median.
    bounds = np.searchsorted(g.row, np.arange(n_spans + 1))
    pooled = np.array(
        [
            [spread(about[0][lo:hi]), spread(about[1][lo:hi])]
            for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)
        ]
    )
    # Each segment's own: the median absolute deviation from its median (`spread_about`).
    for deviation in about:
        np.abs(deviation, out=deviation)
    mad = segment_medians(about, g.links, seen)
    # Every seen segment at once, by the operations that were made segment by segment (so the
    # same numbers; a square as libm's pow makes it, `squares`).
    w, n_k = g.weight[seen], g.counts[seen]
    of_span = seen // n_sensors
    pooled_squared = squares(pooled.reshape(-1)).reshape(pooled.shape)[of_span]
    time_spread = np.sqrt(w * squares(MAD_TO_STD * mad[:, 0]) + (1 - w) * pooled_squared[:, 0])
    speed_spread = np.sqrt(w * squares(MAD_TO_STD * mad[:, 1]) + (1 - w) * pooled_squared[:, 1])
    at = (seen % n_sensors, g.spans[of_span])
    model.log_bias[at] = posterior_centre(
        centre[seen, 0], time_spread, n_k, model.log_bias[at], params.travel_time_spread
    )
    model.log_speed_ratio[at] = posterior_centre(
        centre[seen, 1], speed_spread, n_k, model.log_speed_ratio[at], params.velocity_change_spread
    )
    model.time_spread[at] = time_spread
    model.speed_spread[at] = speed_spread
    unseen = np.flatnonzero(g.counts == 0)
    at = (unseen % n_sensors, g.spans[unseen // n_sensors])
    model.time_spread[at] = pooled[unseen // n_sensors, 0]
    model.speed_spread[at] = pooled[unseen // n_sensors, 1]


def segment_medians(
    columns: Sequence[FloatArray], segment: list[IntArray], seen: IntArray
) -> FloatArray:
    """The median of each of `columns` (one value a link) over each segment seen, a row a
    segment: `median` of each, at once where `robust.run_medians` can."""
    members = [segment[k] for k in seen]
    sizes = np.array([m.size for m in members], dtype=np.int64)
    # run_medians declines runs longer than SHORT_ARRAY: then the links are not gathered for it
    # (at 10^6 detections, a gather of every link's values cost as much as the medians).
    if members and sizes.max() <= SHORT_ARRAY:
        at = np.concatenate(members)
        at_once = run_medians(np.stack([column[at] for column in columns], axis=1), sizes)
        if at_once is not None:
            return at_once
    # Segment by segment, column by column, each segment's values gathered at once.
    return np.array(
        [[median(column[m]) for column in columns] for m in members], dtype=np.float64
    ).reshape(len(members), len(columns))


def pace_deviations(s: Sensors, track: IntArray, confident: IntArray) -> FloatArray:
    """How far each confident detection's relative speed lies from its track's mean."""
    if not confident.size:
        return np.zeros(0)
    # Summed by track index (not by rank among the tracks, which took a sort): each track's sum
    # adds the same values in the same order, so the same means.
    which = track[confident]
    relative = s.relative_speed[confident]
    mean = np.bincount(which, relative)[which] / np.bincount(which)[which]
    deviation: FloatArray = relative - mean
    return deviation


def learn_tails(
    s: Sensors,
    params: AssignmentParams,
    model: SegmentModel,
    links: list[Links],
    deviation: FloatArray,
) -> None:
    """The tails of the three residuals, measured in the units the costs use. They are one shape
    for the whole road, so an even sample of the links pins them (a million links' residuals
    would cost memory)."""
    if links:
        a_all = np.concatenate([a for a, _ in links])
        b_all = np.concatenate([b for _, b in links])
        step = max(1, a_all.size // TAIL_SAMPLE)
        pairs = Pairs.between(s, model, params, a_all[::step], b_all[::step])
        model.time_tails = Tails.fit(pairs.r_time, model.time_tails)
        model.speed_tails = Tails.fit(pairs.ratio / pairs.speed_spread, model.speed_tails)
    if deviation.size:
        model.level_tails = Tails.fit(deviation / model.preferred_speed_spread, model.level_tails)


def best_skews(
    dt: FloatArray, dx: FloatArray, speed_a: FloatArray, speed_b: FloatArray, here: list[IntArray]
) -> FloatArray:
    """The share w of each segment's travel time best predicted from its far end's speed:
    travel = bias * dx * ((1 - w) / v_a + w / v_b) with the least robust spread of log errors,
    over the segment's links `here` (indices into the links' arrays; an even sample of a few
    hundred pins the skew as well as all of them would). Where speeds change at a known place
    (braking for a slow zone just before its sensor), one end's speed explains most of the time.
    The medians of the segments' errors come from one sort where they are short
    (`robust.run_medians`), else segment by segment."""
    learned = np.full(len(here), KINEMATIC_SKEW)
    some = [i for i, h in enumerate(here) if h.size >= SKEW_MIN_LINKS]
    if not some:
        return learned
    at = np.concatenate([here[i] for i in some])
    sizes = np.array([here[i].size for i in some], dtype=np.int64)
    errors = skew_errors(dt[at], dx[at], speed_a[at], speed_b[at])
    centre = run_medians(errors, sizes)
    spread = (
        None if centre is None else run_medians(np.abs(errors - np.repeat(centre, sizes, 0)), sizes)
    )
    if spread is None:
        spread = np.array(
            [
                column_medians(np.abs(own - column_medians(own)))
                for own in np.split(errors, np.cumsum(sizes)[:-1])
            ]
        )
    best = np.argmin(spread, axis=1)
    # The symmetric prediction stands unless another share is clearly better: beyond the
    # sampling error of a spread measured on this many links.
    symmetric = spread[:, SKEW_GRID.size // 2]
    margin = symmetric * (1.0 - SKEW_SIGNIFICANCE / np.sqrt(sizes))
    unclear = spread[np.arange(sizes.size), best] > margin
    learned[some] = np.where(unclear, KINEMATIC_SKEW, SKEW_GRID[best])
    return learned


def skew_errors(
    dt: FloatArray, dx: FloatArray, speed_a: FloatArray, speed_b: FloatArray
) -> FloatArray:
    """log(travel time / its prediction) of each link (a row) at each skew of SKEW_GRID."""
    pace_a = (dx / speed_a)[:, None]
    pace_b = (dx / speed_b)[:, None]
    errors: FloatArray = np.log(dt[:, None] / ((1.0 - SKEW_GRID) * pace_a + SKEW_GRID * pace_b))
    return errors


def posterior_centre(
    measured: FloatArray,
    spread: FloatArray,
    count: IntArray,
    prior: FloatArray,
    prior_spread: float,
) -> FloatArray:
    """Precision-weighted mean of a measured centre (from `count` values) and a prior guess,
    segment by segment."""
    data_precision = count / squares(np.maximum(spread, MIN_RELATIVE_SPREAD))
    prior_precision = 1.0 / prior_spread**2
    return (data_precision * measured + prior_precision * prior) / (
        data_precision + prior_precision
    )


def squares(values: FloatArray) -> FloatArray:
    """Each value squared as a float's `** 2` squares it (libm's pow, which differs from numpy's
    x * x in the last bit of about one square in a thousand here), so that numbers worked out
    for all segments at once are those worked out one segment at a time."""
    return np.array([value**2 for value in values.tolist()], dtype=np.float64)
