"""`assignment` for live steps: link a window with a model learned at an earlier step.

Offline, `assignment` learns the road from the detections it is given: the prior
(`segment_prior`, the mode of the travel-time ratios over every pair of end sensors'
detections: a third of the associator's time on a live window), then `em_rounds` of linking
and learning, then the re-pairing sweeps. A live step's window overlaps the previous one in
most of its detections, and a road's behaviour changes over minutes, not over the seconds
between steps. So a step runs the whole loop (`link_and_learn`, `repair_and_judge`, as
`AssignmentAssociator.group` runs them) only to learn: the model it ends with (and its prior)
is kept, and the steps of the next `RELEARN_SECONDS` of data link their windows with it in one
pass (`em_rounds + 1` offline), then re-pair, confirm and judge their links as offline.

The model is learned again, by the whole loop, at the first step, after `RELEARN_SECONDS` of
data, after the parameters changed, and when a window's sensors or features differ from those
it was learned on (its arrays are indexed by them). It is kept only when it was learned from
`MIN_LINKS` links or more between every two neighbouring sensors: the first seconds of a
stream hold few vehicles at the far sensors, and a model learned there linked the next ten
minutes badly (51 % accuracy on the SUMO replay, against 79 %). It is the worker's, in memory:
a worker that restarts, or takes over a lease, learns it again; what is published, and once,
does not depend on it.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass
from typing import Any

import numpy as np

from roadlink.association.associators.assignment import AssignmentParams, SegmentModel
from roadlink.association.associators.assignment.associator import (
    link_and_learn,
    repair_and_judge,
)
from roadlink.association.associators.assignment.confidence import cut_weak_links
from roadlink.association.associators.assignment.confirmation import confirm_targets
from roadlink.association.associators.assignment.duplicates import (
    duplicate_followers,
    for_every_report,
    join_duplicates,
    once_each,
    repeat_of,
)
from roadlink.association.associators.assignment.params import within_time_scale
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.sensors import Sensors, arrange
from roadlink.association.detections import Detections, FloatArray, IntArray

# Data seconds a model is used for before it is learned again: traffic changes over tens of
# minutes (a queue forms, a peak passes); at 2,000 detections/s of the SUMO replay, a model is
# learned every 4 s of wall time.
RELEARN_SECONDS = 600.0
# Links a model must have been learned from between every two neighbouring sensors to be kept.
MIN_LINKS = 30
# Deployments whose models a worker keeps (a model is a few arrays per sensor).
MAX_MODELS = 256


@dataclass(frozen=True)
class Learned:
    """What a step learned, for the next step of the same live association."""

    key: tuple[Any, ...]  # the parameters, sensors and features it was learned with
    prior: SegmentModel  # what learning shrinks towards (anchors learn from it)
    clock: float  # the data clock it was learned at
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

    def put(self, deployment: Any, learned: Learned | None) -> None:
        """Keep `learned` for the deployment's next step (None: nothing worth keeping)."""
        if learned is None:
            self._models.pop(deployment, None)
            return
        self._models[deployment] = learned
        self._models.move_to_end(deployment)
        while len(self._models) > self._size:
            self._models.popitem(last=False)


def associate_window(
    d: Detections, params: AssignmentParams, clock: float, learned: Learned | None
) -> tuple[IntArray, FloatArray, Learned | None]:
    """The window's groups (-1: unassigned) and link confidences, as `AssignmentAssociator`
    answers them, and the model for the next step (None: none worth keeping). `d` must hold
    two sensor positions or more and no labels (the associator never sees them)."""
    s = arrange(d, params)
    repeats = repeat_of(s, d)
    if repeats is not None:
        # Each report once, as offline (`AssignmentAssociator.group`).
        once, at = once_each(repeats)
        groups, judged, learned = associate_window(d.take(once), params, clock, learned)
        return (*for_every_report(repeats, once, at, groups, judged), learned)
    effective = within_time_scale(params, s.typical_travel_time())
    key = _key(params, s, d)
    if learned is not None and learned.key == key and clock - learned.clock < RELEARN_SECONDS:
        # One pass with the model; two where lane order anchors the links, as offline their
        # weights come from tracks built without them.
        prior, model = learned.prior, learned.model
        rounds = 2 if _anchored(s, effective) else 1
    else:
        learned = None
        prior = segment_prior(s, effective.max_skip + 1, effective)
        model, rounds = prior, effective.em_rounds + 1
    leader = duplicate_followers(s, effective)
    built, model, anchor = link_and_learn(s, effective, prior, model, rounds, leader=leader)
    track, confidence = repair_and_judge(s, effective, model, built, anchor)
    target = confirm_targets(s, model, effective, track, anchor)
    target, kept = cut_weak_links(s, target, confidence, effective.min_confidence)
    if learned is None and _learned_enough(s, built):
        learned = Learned(key, prior, clock, model)
    return join_duplicates(target, leader), kept, learned


def _learned_enough(s: Sensors, track: IntArray) -> bool:
    """Whether every segment between neighbouring sensors has MIN_LINKS links in `track`: a
    window of the first seconds of a stream holds few vehicles at the far sensors, and a model
    learned there (its prior a mode over a few pairs) would link the next windows badly."""
    assigned = np.flatnonzero(track >= 0)
    chain = assigned[np.lexsort((s.sensor[assigned], track[assigned]))]
    a, b = chain[:-1], chain[1:]
    neighbours = (track[a] == track[b]) & (s.sensor[b] - s.sensor[a] == 1)
    links = np.bincount(s.sensor[a[neighbours]], minlength=s.positions.size)
    return bool(links[:-1].min() >= MIN_LINKS)  # two sensors or more: never empty


def _key(params: AssignmentParams, s: Sensors, d: Detections) -> tuple[Any, ...]:
    """What a model's arrays are indexed by: sensors (positions) and, where detectors report
    features, the lanes and classes (indices into the window's own class names)."""
    features: tuple[Any, ...] | None = None
    if s.features is not None:
        names = np.unique(d.vehicle_class[d.has_vehicle_class].astype(str))
        features = (s.features.n_lanes, tuple(names.tolist()))
    return (params.model_dump_json(), s.positions.tobytes(), features)


def _anchored(s: Sensors, params: AssignmentParams) -> bool:
    return bool(
        params.lane_anchors
        and params.feature_weight > 0
        and s.features is not None
        and s.features.has_lane()
    )
