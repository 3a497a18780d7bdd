"""`assignment` for live steps: link a window with the model the previous step learned.

Offline, `assignment` learns the road from the detections it is given: the prior
(`segment_prior`, the mode of the travel-time ratios over every pair of end sensors'
detections; the costliest stage on a live window, a third of the associator's time), then
`em_rounds` of linking and learning, then the re-pairing sweeps. A live step's window overlaps
the previous step's in most of its detections, and the road's behaviour changes over minutes,
not over the seconds between steps. So a step here starts from the model the previous step
learned and links once (one pass, not `em_rounds + 1`), re-pairs and confirms as offline, and
learns the model again from its own tracks for the next step: one EM round a step, spread over
the stream. The prior, which learning shrinks towards and falls back on, is computed again every
`PRIOR_SECONDS` of data.

A step without a usable model runs the offline associator's whole loop, stage by stage as
`AssignmentAssociator.group` runs them, and keeps what it learned: the first step, one after
the worker restarted or the lease moved to another worker (the model is the worker's, in
memory: it changes how well a step links, never what is published once), after the
parameters changed, or once the window's sensors or features differ from those the model was
learned on (its arrays are indexed by them).
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadlink.association.associators.assignment import AssignmentParams, SegmentModel
from roadlink.association.associators.assignment.anchors import (
    Anchors,
    lane_order_anchors,
    weigh_anchors,
)
from roadlink.association.associators.assignment.confidence import (
    cut_weak_links,
    link_confidence,
)
from roadlink.association.associators.assignment.confirmation import confirm_targets
from roadlink.association.associators.assignment.learning import learn_segments
from roadlink.association.associators.assignment.params import within_time_scale
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.refine import refine_boundaries
from roadlink.association.associators.assignment.sensors import Sensors, arrange
from roadlink.association.associators.assignment.tracks import build_tracks, duplicate_followers
from roadlink.association.detections import Detections, FloatArray, IntArray

# Data seconds between two computations of the prior: the road's free-flow behaviour, which
# learning only shrinks towards, drifts over tens of minutes; this is a few windows.
PRIOR_SECONDS = 600.0
# Deployments whose models a worker keeps (a model is a few arrays per sensor).
MAX_MODELS = 256


@dataclass(frozen=True)
class Learned:
    """What a step learned, for the next step of the same live association."""

    key: tuple[Any, ...]  # the parameters, sensors and features it was learned with
    prior: SegmentModel
    prior_clock: float  # the data clock the prior was computed at
    model: SegmentModel


class Models:
    """The worker's learned models, by deployment, the least recently used dropped first."""

    def __init__(self, size: int = MAX_MODELS) -> None:
        self._size = size
        self._models: OrderedDict[Any, Learned] = OrderedDict()

    def get(self, deployment: Any) -> Learned | None:
        learned = self._models.get(deployment)
        if learned is not None:
            self._models.move_to_end(deployment)
        return learned

    def put(self, deployment: Any, learned: Learned) -> None:
        self._models[deployment] = learned
        self._models.move_to_end(deployment)
        while len(self._models) > self._size:
            self._models.popitem(last=False)


def associate_window(
    d: Detections, params: AssignmentParams, clock: float, learned: Learned | None
) -> tuple[IntArray, FloatArray, Learned]:
    """The window's groups (-1: unassigned) and link confidences, as `AssignmentAssociator`
    answers them, and the model for the next step. `d` must hold two sensor positions or more
    and no labels (the associator never sees them)."""
    s = arrange(d, params)
    effective = within_time_scale(params, s.typical_travel_time())
    key = _key(params, s, d)
    warm = learned is not None and learned.key == key
    if warm and learned is not None and clock - learned.prior_clock < PRIOR_SECONDS:
        prior, prior_clock = learned.prior, learned.prior_clock
    else:
        prior, prior_clock = segment_prior(s, effective.max_skip + 1, effective), clock
    if warm and learned is not None:
        # One pass from the last step's model; two where lane order anchors the links, as
        # offline their weights come from tracks built without them.
        model, rounds = learned.model, 2 if _anchored(s, effective) else 1
    else:
        model, rounds = prior, effective.em_rounds + 1
    built, model, anchor = _link(s, effective, prior, model, rounds)
    track, confidence = _repair(s, effective, model, built, anchor)
    target = confirm_targets(s, model, effective, track)
    target, kept = cut_weak_links(s, target, confidence, effective.min_confidence)
    # Learned from the sequential pass's tracks, as offline: learning from the re-paired ones
    # cost half a point of accuracy on the SUMO replay (docs/benchmarks.md).
    following = learn_segments(s, built, effective, prior)
    return target, kept, Learned(key, prior, prior_clock, following)


def _key(params: AssignmentParams, s: Sensors, d: Detections) -> tuple[Any, ...]:
    """What a model's arrays are indexed by: sensors (positions) and, where detectors report
    features, the lanes and classes (indices into the window's own class names)."""
    features: tuple[Any, ...] | None = None
    if s.features is not None:
        names = np.unique(d.vehicle_class[d.has_vehicle_class].astype(str))
        features = (s.features.n_lanes, tuple(names.tolist()))
    return (params.model_dump_json(), s.positions.tobytes(), features)


def _anchored(s: Sensors, params: AssignmentParams) -> bool:
    return bool(params.lane_anchors and params.feature_weight > 0 and s.features is not None)


def _link(
    s: Sensors, params: AssignmentParams, prior: SegmentModel, model: SegmentModel, rounds: int
) -> tuple[IntArray, SegmentModel, Anchors | None]:
    """`rounds` sequential passes from `model`, learning between them (the associator's loop)."""
    leader = duplicate_followers(s, params)
    track = np.zeros(0, dtype=np.int64)
    anchor = None
    for r in range(rounds):
        track = build_tracks(s, model, params, leader, None, 0.0, 0.0, anchor)
        if r + 1 < rounds:
            model = learn_segments(s, track, params, prior)
            if anchor is None and params.lane_anchors and params.feature_weight > 0:
                anchor = weigh_anchors(s, *lane_order_anchors(s, model, params), track)
    return track, model, anchor


def _repair(
    s: Sensors,
    params: AssignmentParams,
    model: SegmentModel,
    track: IntArray,
    anchor: Anchors | None,
) -> tuple[IntArray, FloatArray]:
    """The re-pairing sweeps; the last one judges the links it keeps."""
    confidence = np.full(track.size, np.nan)
    for sweep in range(params.refine_sweeps):
        last = sweep + 1 == params.refine_sweeps
        track = refine_boundaries(
            s, model, params, track, confidence if last else None, anchor=anchor
        )
    if params.refine_sweeps == 0:
        confidence = link_confidence(s, model, params, track)
    return track, confidence
