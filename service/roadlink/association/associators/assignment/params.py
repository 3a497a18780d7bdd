"""The associator's parameters, its fixed hyper-parameters, and the scaling of those in time units.

`AssignmentParams` are what a caller may set (their names and bounds are the API's contract). The
constants below are the model's other choices, named here once, by the stage that uses them.
Numbers that are no choice live where they are used: the kinematic skew of 0.5
(`sensors.KINEMATIC_SKEW`), the normal MAD factor (`robust`), and the matching solver's knobs,
which tune its speed, not the model (`matching`). `within_time_scale` says which parameters the
associator holds to the detections' own time scale; the result reports the values it ran with
(`effective_params`) next to the ones asked for.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from roadlink.association.associators.base import AssociatorParams

# The prior (`prior`): each segment's travel-time bias is searched up to 10x off the kinematic
# guess, in bins of 5 %, from a sample of this many detections per sensor.
PRIOR_LOG_RANGE = float(np.log(10.0))
PRIOR_BIN = 0.05
# Times stamped in steps of at least this many bins of the shortest segment's travel time are
# spread within their step before the prior's histograms (`Sensors.within_step`).
PRIOR_STEP_BINS = 0.25
PRIOR_SAMPLE = 400
# Unrelated pairs are counted by moving every pair's travel time by this many typical kinematic
# travel times either way, in this many steps a side, over at most this many pairs
# (`prior.CandidatePairs.excess`). Inner edges of 0.25-0.5 and outer ones of 0.75-1 gave the same
# SUMO and simulator accuracies; an inner edge of 0 lets a bump count as its own background (the
# congested slow zone of tests/association: -30 points), an outer edge of 2 blurs the waves of a
# queue (SUMO dense and bottleneck traffic: -4 to -7 points).
PRIOR_SIDEBANDS = (0.25, 0.75)
PRIOR_SIDEBAND_STEPS = 8
PRIOR_BACKGROUND_PAIRS = 100_000
# That search also looks at the pairs alone whose relative speeds differ by at most this share of
# the spread of relative speeds at a sensor.
PRIOR_AGREEMENT = 0.5
# A pile-up of pairs away from the kinematic prediction is believed only when it holds this many
# standard deviations (Poisson) more pairs than the kinematic prediction's own bin.
PRIOR_SIGNIFICANCE = 5.0
# A weaker bump's bias (this many standard deviations, in the selection that shows it most, and
# PRIOR_WEAK_SUPPORT in the other, in the same place) is kept where matching the detections under
# it confirms it (weak_bias.py).
PRIOR_WEAK_SIGNIFICANCE = 2.0
PRIOR_WEAK_SUPPORT = 1.0
# Fewer sampled detections than this cannot reach that significance (a handful of targets): their
# mode is taken as it is, as long as it stands above the background at all, unless the kinematic
# prediction's own bin holds a bump of at least PRIOR_KINEMATIC_BUMP standard deviations that the
# mode does not beat by PRIOR_KINEMATIC_LEAD (`prior.BiasHistogram.kinematic_stands`).
PRIOR_TEST_SAMPLE = 40
PRIOR_KINEMATIC_BUMP = 1.5
PRIOR_KINEMATIC_LEAD = 2.0
# Traffic flows where speeds reach at least this share of the road's fastest sensor's median
# speed; slower, it is a queue's: vehicles are stored between sensors (`ends`), a sensor they
# stand on falls silent (`silences`), vehicles pass neighbouring sensors in waves
# (`clock_steps`).
FLOWING_SHARE = 0.5
# A sensor with fewer than PRIOR_TEST_SAMPLE detections and under this share of a busy
# neighbour's stopped reporting early in the batch, or started late (`Sensors.sparse`).
SPARSE_SHARE = 0.5
# A segment either of whose sensors saw fewer detections than this has no mode: the kinematic
# prediction stands.
PRIOR_MIN_DETECTIONS = 3
# The histogram of pairs is smoothed with this kernel (the variance of a smoothed count with its
# square, counts being Poisson); every variance gets this pseudo-count, so no bin is ever certain.
PRIOR_SMOOTHING = (1.0, 2.0, 1.0)
PRIOR_PSEUDO_COUNT = 1.0
# The centre of the highest bump: the median of the values within this many bins of it.
PRIOR_PEAK_BINS = 2

# Heavy tails of the residuals (`model.Tails`): learned from the confident tracks' links, starting
# from this prior (weight, scale), by EM on an even sample of at most TAIL_SAMPLE residuals.
PRIOR_TAILS = (0.01, 3.0)
TAIL_MIN_SAMPLES = 30
TAIL_SAMPLE = 5000
TAIL_EM_ITERATIONS = 50
TAIL_EM_TOLERANCE = (1e-4, 1e-3)  # the EM stops once weight and scale move less than these
TAIL_WEIGHT_RANGE = (0.001, 0.5)
TAIL_MIN_SCALE = 2.0  # the tail stays at least this much wider than the core, so it is a tail
TAIL_MAX_SCALE = 30.0
TAIL_REACH_POINTS = 513  # the grid on which the largest residual within a budget is found

# Gating (`gating`): a link's mean speed may exceed the fastest speed measured at its sensors by
# this factor at most.
FASTEST_SHARE = 1.5

# Re-pairing (`refine`): the gate there is this many times `gate_cost`, since splitting a track
# the forward pass built must pay for itself.
REFINE_GATE_FACTOR = 2.0

# Learning (`learning`): segments learn from the tracks with at least this many detections.
CONFIDENT_TRACK_LENGTH = 3
# A learned spread is never trusted below this: sensors measure to a per cent at best.
MIN_RELATIVE_SPREAD = 0.01
# The pace term weighs nothing where the speed readings' error (learned from the tracks) is below
# the first number, and in full above the second. Real speed changes read as error too: 1.8-2.1 %
# on the simulator's 5 % fluctuating speeds (2.1 % on the first round's rougher tracks), where the
# term changed accuracy by 0.01 % and cost 28 % more time (weighed a fifth) and 40 % more memory
# (weighed 6 %, in one round); exact-speed SUMO traffic reads 0.7-1.5 %.
PACE_READING_ERROR = (0.025, 0.04)
# The skew is searched in [0, 1] in this many steps, on an even sample of this many links, from
# this many links on; it must beat the symmetric prediction's spread by this many sampling
# errors (each 1 / sqrt(links)).
SKEW_STEPS = 20
SKEW_SAMPLE = 400
SKEW_MIN_LINKS = 3
SKEW_SIGNIFICANCE = 2.0

# Confirmation (`confirmation`): a target's longest plausible travel time over a segment is its
# learned bias this many spreads up.
LONGEST_TRAVEL_SPREADS = 2.0

# The parameters in time units are held to these shares of a typical travel time between
# neighbouring sensors (`within_time_scale`).
DUPLICATE_WINDOW_SHARE = 0.25
TIMESTAMP_NOISE_SHARE = 0.02


# The largest cost a parameter may set (a link's cost is a sum of -2 log densities: 200 is a
# residual of 14 standard deviations). Beyond it every pair within the time gate is a candidate
# link, and the matching's work grows with their square (1e14 ran for minutes on 5,000
# detections).
MAX_COST = 200.0


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
        le=MAX_COST,
        description="Largest cost of a link (a sum of -2 log densities of standardised "
        "residuals: r^2 in the core, flatter in the learned heavy tails, so 18 is about four "
        "core standard deviations); leaving a detection unlinked "
        "costs half of it. Lower leaves more detections as separate tracks; higher links more "
        "boldly.",
    )
    miss_cost: float = Field(
        default=6.0,
        ge=0,
        le=MAX_COST,
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
    # This package says "speed" for the scalar a detector measures; the parameters below that say
    # "velocity" (velocity_change_*, velocity_floor, duplicate_velocity_tolerance) keep it because
    # their names are API contract, chosen after the detection contract's `velocity` column.
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
    feature_weight: float = Field(
        default=1.0,
        ge=0,
        le=10,
        description="Weight of the detector features (lane, length, class) where detections "
        "report them: each adds the log likelihood ratio of 'same vehicle' against 'another "
        "vehicle at that sensor', learned from the data. 0 ignores them.",
    )
    lane_anchors: bool = Field(
        default=True,
        description="Where detections report lane and length: favour the links that lane order "
        "makes sure of (each lane's detections at two neighbouring sensors aligned in time "
        "order: no vehicle passes another in its lane, and followers take about the same "
        "time), each as much as its chain beat the alignments that shift it, in each segment "
        "as much as the tracks built without them contradict them; and exchange two links "
        "between the same lanes that cross (one vehicle passing another that keeps its lane) "
        "where the segment's tracks say crossing is rarer than the exchange costs. Decisive in "
        "queues; false: speeds, times and features alone.",
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
    pace_weight: float = Field(
        default=1.0,
        ge=0,
        le=10,
        description="Weight of the penalty on a link whose pace (time per metre, relative to its "
        "segment's typical) departs from the pace of the track's link before it, or after it. "
        "Timestamps are exact where speed readings are not, and drivers hold their pace, so this "
        "tells neighbouring vehicles apart even when speeds are read with a 5-10 % error. It "
        "weighs only where the tracks find the speed readings off by 2.5 % or more (in full "
        "from 4 %). 0 ignores it.",
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
        le=MAX_COST,
        description="Least total saving of a track's links over leaving its detections apart "
        "(the sum of gate_cost - link cost); a weaker track's detections are judged one by "
        "one, each a false alarm unless the batch's time window explains it. Higher breaks "
        "more doubtful short tracks; 0 keeps every track.",
    )
    min_confidence: float = Field(
        default=0.0,
        ge=0,
        le=1,
        description="Links less sure than this (their confidence, the approximate probability "
        "that the link joins one vehicle) are cut: the pieces on either side stay targets of "
        "their own. 0 keeps every link; 0.5 keeps the links more likely right than wrong.",
    )
    duplicate_window: float = Field(
        default=0.5,
        ge=0,
        description="Two reports of one sensor at most this far apart in time (time units) with "
        "near-equal speed (and the same lane and class where both report them) may be one passage "
        "reported twice: only one of them is linked into a track, and the other joins its target. "
        "Held to at most a quarter of a typical travel time between neighbouring sensors, so "
        "the default also suits minutes or hours. 0 disables.",
    )
    duplicate_velocity_tolerance: float = Field(
        default=0.05,
        ge=0,
        le=1,
        description="Largest relative speed difference of two reports taken as a duplicate.",
    )


def within_time_scale(
    params: AssignmentParams, typical_travel_time: float | None
) -> AssignmentParams:
    """The parameters, with those in time units (`duplicate_window`, `timestamp_noise`) held to
    a share of a typical travel time between neighbouring sensors (None: one sensor, no limit).

    Units are the caller's. Their defaults (0.5 and 0.02) are seconds-sized; a deployment that
    times in minutes or hours (positions in km, speeds in km/h) would otherwise take every
    report within half an hour for a duplicate, and a timestamp error of a minute for noise.
    With seconds and road traffic the limits are far above the defaults and change nothing."""
    if typical_travel_time is None:
        return params
    return params.model_copy(
        update={
            "duplicate_window": min(
                params.duplicate_window, DUPLICATE_WINDOW_SHARE * typical_travel_time
            ),
            "timestamp_noise": min(
                params.timestamp_noise, TIMESTAMP_NOISE_SHARE * typical_travel_time
            ),
        }
    )
