"""The `assignment` associator: its stages in the order they run."""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from roadlink.association.associators.assignment.anchors import (
    Anchors,
    lane_order_anchors,
    weigh_anchors,
)
from roadlink.association.associators.assignment.arrays import filled, same
from roadlink.association.associators.assignment.clock_drift import drift_warnings
from roadlink.association.associators.assignment.clock_steps import step_warnings
from roadlink.association.associators.assignment.clocks import clock_warnings
from roadlink.association.associators.assignment.confidence import (
    cut_weak_links,
    link_confidence,
)
from roadlink.association.associators.assignment.confirmation import (
    confirm_targets,
    few_links_warnings,
    noisy_sensor_warnings,
)
from roadlink.association.associators.assignment.duplicates import (
    duplicate_followers,
    for_every_report,
    join_duplicates,
    once_each,
    repeat_of,
)
from roadlink.association.associators.assignment.learning import learn_ends, learn_segments
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import (
    AssignmentParams,
    within_time_scale,
)
from roadlink.association.associators.assignment.prior import segment_prior
from roadlink.association.associators.assignment.refine import refine_boundaries
from roadlink.association.associators.assignment.sensor_order import order_warnings
from roadlink.association.associators.assignment.sensors import (
    Sensors,
    arrange,
    one_speed_warnings,
)
from roadlink.association.associators.assignment.tracks import (
    LevelRelay,
    SweepSetup,
    build_tracks,
)
from roadlink.association.associators.assignment.weak_bias import speed_factor_warnings
from roadlink.association.associators.base import Associator, Progress
from roadlink.association.detections import Detections, FloatArray, IntArray

LOG = logging.getLogger(__name__)


class AssignmentAssociator(Associator):
    name: ClassVar[str] = "assignment"
    description: ClassVar[str] = (
        "Constraint-aware tracking: links each sensor's detections to the tracks of the previous "
        "sensors by sparse minimum-cost assignment with a kinematic cost, bridging missed "
        "detections, then learns each road segment's travel-time behaviour and re-associates. "
        "One passage per sensor per target (a passage reported twice keeps both reports "
        "there); false alarms stay unassigned; needs no labels and no target count."
    )
    # `edges` (log_ndtr) and `matching` (connected components, the sparse assignment).
    imports_on_first_use: ClassVar[tuple[str, ...]] = ("scipy.special", "scipy.sparse.csgraph")
    # Its peak resident set less the set after the read: 228 MB at 10^6 detections (the
    # scaling data of benchmarks/); somewhat less, so that touching it does not raise the peak.
    heap_per_detection: ClassVar[int] = 200
    Params = AssignmentParams
    params: AssignmentParams

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        """Arrange the detections, hold the parameters in time units to their time scale, start
        from the prior, link and learn for `em_rounds` rounds and once more, re-pair for
        `refine_sweeps` sweeps, and keep the tracks that are targets."""
        s = arrange(detections, self.params)
        repeats = repeat_of(s, detections)
        if repeats is not None:
            return self._group_once(detections, repeats, progress)
        params = within_time_scale(self.params, s.typical_travel_time())
        self.effective_params = params
        prior = segment_prior(s, params.max_skip + 1, params)
        # Said once a run here, not by `arrange` and the prior, which live association repeats
        # every step.
        self.warnings = (
            *order_warnings(s.positions, s.swapped),
            *clock_warnings(s.positions, s.clock_offsets, s.stepped_sensors),
            *step_warnings(s.positions, s.clock_offsets, list(s.clock_steps)),
            *drift_warnings(s.positions, list(s.clock_drifts)),
            *speed_factor_warnings(s.positions, prior.log_bias[:-1, 1], s.median_speed),
            *one_speed_warnings(s),
        )
        for warning in self.warnings:
            LOG.warning("%s", warning)
        # Every pass (a linking round or a re-pairing sweep) visits each sensor once and costs
        # about the same: progress is the share of passes done.
        rounds = params.em_rounds + 1
        passes = Passes(progress, rounds + params.refine_sweeps)
        sweep = SweepSetup()
        leader = duplicate_followers(s, params)
        track, model, anchor = link_and_learn(
            s, params, prior, prior, rounds, passes, sweep, leader
        )
        track, confidence = repair_and_judge(s, params, model, track, anchor, passes, rounds, sweep)
        # The sweep's window edges (two numbers a detection) are not the confirmation's.
        del sweep
        target = confirm_targets(s, model, params, track, anchor)
        target, self.link_confidence = cut_weak_links(s, target, confidence, params.min_confidence)
        target = join_duplicates(target, leader)
        for warning in (*few_links_warnings(s, target), *noisy_sensor_warnings(s, target)):
            LOG.warning("%s", warning)
            self.warnings += (warning,)
        return target

    def _group_once(
        self, detections: Detections, repeats: IntArray, progress: Progress | None
    ) -> IntArray:
        """The groups of the detections each report once (`duplicates.repeat_of`), a repeat in
        its report's group, carrying no link confidence (nothing links to it)."""
        kept, at = once_each(repeats)
        groups = self.group(detections.take(kept), progress)
        assert self.link_confidence is not None
        every_group, self.link_confidence = for_every_report(
            repeats, kept, at, groups, self.link_confidence
        )
        return every_group


@dataclass(frozen=True)
class Passes:
    """Where progress is reported (None: nowhere), and how many passes the whole run makes."""

    progress: Progress | None = None
    total: int = 1


def link_and_learn(
    s: Sensors,
    params: AssignmentParams,
    prior: SegmentModel,
    model: SegmentModel,
    rounds: int,
    passes: Passes = Passes(),
    sweep: SweepSetup | None = None,
    leader: IntArray | None = None,
) -> tuple[IntArray, SegmentModel, Anchors | None]:
    """`rounds` sequential passes from `model`, learning the segments between them (towards
    `prior`), and lane order's anchors from the first tracks, their chains drawn again once with
    the next tracks' lengths: the tracks, the last model, the anchors (None where none were
    weighed).

    A round that builds the tracks the round before built, with the same anchors, ends the
    loop: learning is a function of the tracks, so every later round would learn this round's
    model again and build these tracks again (on a paper-size batch the first round's tracks
    are usually final, and the rounds after it were most of the associator's time).

    A round whose model the re-pairing sweep may use (one that may end the loop, or the last)
    works out the sweep's gating and edges into `sweep`, where given (`tracks.SweepSetup`).
    `leader`: each report's twin it may copy (`duplicates.duplicate_followers`, found here where
    not given)."""
    if leader is None:
        leader = duplicate_followers(s, params)
    track = first = np.zeros(0, dtype=np.int64)
    anchor, chains, ends = None, None, model.ends
    # Without lengths a chain drawn again would be the same.
    redraw = s.features is not None and s.features.has_length()
    learned_from = None  # the tracks the current model was learned from, with these anchors
    relay = LevelRelay()  # the last pass's tracks and their levels, for the next to foresee
    for r in range(rounds):
        final = learned_from is not None or r + 1 == rounds  # perhaps the sweep's model
        track = build_tracks(
            s,
            model,
            params,
            leader,
            passes.progress,
            r / passes.total,
            1.0 / passes.total,
            anchor,
            sweep if final and params.refine_sweeps > 0 else None,
            learned_from,
            relay,
        )
        if learned_from is not None and same(track, learned_from):
            if passes.progress:
                passes.progress(rounds / passes.total)
            break
        if r + 1 < rounds:
            if sweep is not None:
                sweep.forget()  # this round's model, which the next round's replaces
            model = learn_segments(s, track, params, prior, anchor)
            if r == 0 and ends is None:
                # From the first tracks only, built without them: tracks built with these costs
                # break more where they apply, and learning from them again would find more ends
                # there each round (live association's steps bring them in their model).
                ends = learn_ends(s, track, model, leader)
            model.ends = ends
            learned_from = track
            if anchor is None and params.lane_anchors and params.feature_weight > 0:
                # Lane order needs the model learned from the first tracks (the length error
                # among it) and is weighed by them; it is evidence from lane and length, so
                # feature_weight 0 ignores it too.
                first, chains = track, lane_order_anchors(s, model, params)
                anchor = weigh_anchors(s, chains.predecessor, chains.margin, first)
            elif anchor is not None and chains is not None and redraw:
                # Where the anchors weigh, the chains are drawn again, once, with each
                # vehicle's lengths averaged along the tracks that the anchors just helped build,
                # on either side of the segment (a second time changed little); still weighed
                # against the first tracks, which no anchor built.
                segments = anchor.weighed_segments(s)
                chains = lane_order_anchors(s, model, params, track, chains, segments)
                anchor, redraw = weigh_anchors(s, chains.predecessor, chains.margin, first), False
            else:
                continue
            if anchor.bonus.any():
                learned_from = None  # the next round's costs change with the anchors
    return track, model, anchor


def repair_and_judge(
    s: Sensors,
    params: AssignmentParams,
    model: SegmentModel,
    track: IntArray,
    anchor: Anchors | None,
    passes: Passes = Passes(),
    done: int = 0,
    setup: SweepSetup | None = None,
) -> tuple[IntArray, FloatArray]:
    """The re-pairing sweeps (after `done` passes of the run), and each link's confidence: the
    last sweep judges the links it keeps (docs/assignment.md, Confidence), or, with no sweep,
    `link_confidence` does.

    The sweeps before the last judge tentatively (until they change a link): a sweep that
    changes none leaves every later sweep the same work, so the loop ends there with its
    judging (on a paper-size batch the first sweep usually changes nothing). Every sweep takes
    its gating and edges from `setup` where the forward pass worked them out with this model."""
    confidence = filled(track.size, np.nan)
    for sweep in range(params.refine_sweeps):
        last = sweep + 1 == params.refine_sweeps
        track, changed = refine_boundaries(
            s, model, params, track, confidence, anchor=anchor, tentative=not last, setup=setup
        )
        if passes.progress:
            passes.progress(
                (done + (sweep + 1 if changed else params.refine_sweeps)) / passes.total
            )
        if not changed:
            break
        if not last:
            confidence[:] = np.nan  # judged in part, before the change
    if params.refine_sweeps == 0:
        confidence = link_confidence(s, model, params, track)
    return track, confidence
