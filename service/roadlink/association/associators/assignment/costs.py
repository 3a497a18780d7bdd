"""What a link costs: a sum of -2 log densities of its standardised residuals."""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from roadlink.association.associators.assignment.features import feature_cost
from roadlink.association.associators.assignment.gating import BoolArray, Pairs
from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.pace import Neighbour, pace_cost
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import FloatArray


@dataclass
class Level:
    """Mean relative speed of some track pieces, and how many detections each mean is over; where
    detectors measure length, the pieces' mean log length and number of length readings; the
    pace of each piece's link next to the one costed (`pace.incoming_pace` of a piece that ends
    in a, `pace.outgoing_pace` of one that starts with b; NaN where it has none, None when no
    piece has one)."""

    mean: FloatArray
    count: FloatArray
    length_mean: FloatArray | None = None
    length_count: FloatArray | None = None
    pace: Neighbour | None = None


def link_cost(
    params: AssignmentParams,
    model: SegmentModel,
    pairs: Pairs,
    before: Level,
    after: Level,
    s: Sensors,
) -> FloatArray:
    """Cost of every candidate link a -> b: a sum of -2 log densities of standardised residuals
    (squared in the core, flatter in the learned heavy tails: `model.Tails`).

    `before` is the mean relative speed (and its number of detections) of the track ending in a,
    `after` that of the track starting with b (b alone, when linking sensor by sensor)."""
    # A driver keeps a preferred speed relative to the traffic around: compare the speeds,
    # relative to their sensors' typical speed, of the two track pieces the link would join.
    # Speed fluctuations are correlated over several sensors, so a mean over many detections is
    # not as sure as 1/n would say: the counts are capped.
    memory = params.preferred_speed_memory
    level_spread = model.preferred_speed_spread * np.sqrt(
        1.0 / np.minimum(before.count, memory) + 1.0 / np.minimum(after.count, memory)
    )
    r_level = (after.mean - before.mean) / level_spread
    # The travel-time error's cost and the weighed speed change's (`Pairs.own_cost`), then:
    cost = (
        pairs.own_cost(model, params)
        + params.preferred_speed_weight * model.level_tails.cost(r_level)
        + params.miss_cost * (pairs.span - 1)
    )
    if model.pace is not None and params.pace_weight > 0:
        cost += params.pace_weight * pace_cost(
            model.pace,
            s,
            pairs,
            Neighbour.unknown(pairs.a.size) if before.pace is None else before.pace,
            Neighbour.unknown(pairs.a.size) if after.pace is None else after.pace,
            params.timestamp_noise,
        )
    if s.features is None or model.features is None or params.feature_weight == 0:
        return cost
    lengths = (
        _or_zeros(before.length_mean, pairs.a.size),
        _or_zeros(before.length_count, pairs.a.size),
        _or_zeros(after.length_mean, pairs.a.size),
        _or_zeros(after.length_count, pairs.a.size),
    )
    evidence = feature_cost(s.features, model.features, s.sensor, pairs.a, pairs.b, lengths)
    return cost + params.feature_weight * evidence


# Far beyond the rounding of a sum of a few costs of a gate's size (a tail's cost at 0 is 0 to
# within about 1e-15).
ROUNDING_MARGIN = 1e-6


def affordable(
    params: AssignmentParams, model: SegmentModel, pairs: Pairs, s: Sensors, bonus: float
) -> Pairs:
    """The candidate links whose `link_cost`, less an anchor's bonus of at most `bonus`, can come
    in under the gate, in their order, each with its own cost (`Pairs.own_cost`) worked out.

    Every term `link_cost` and the forward pass add to a link's own cost is at least 0 (a tail's
    cost, the miss cost, a Cauchy pace change, the window's edges: all weights are at least 0),
    except detector features' evidence (then every link is kept) and the anchors' bonus: so a link
    whose own cost alone reaches the gate plus the largest bonus costs at least the gate, and the
    matching (`cost < gate`) would drop it. At 10^6 detections that is about half of a forward
    pass's candidates, whose other terms are then not worked out."""
    own = pairs.own_cost(model, params)
    if pairs.own is None:
        pairs = replace(pairs, own=own)
    keep = affordable_links(params, model, own, s, bonus)
    return pairs if keep is None or keep.all() else pairs.take(keep)


def affordable_links(
    params: AssignmentParams, model: SegmentModel, own: FloatArray, s: Sensors, bonus: float
) -> BoolArray | None:
    """Which links `affordable` keeps, by their own costs (None: every one)."""
    if s.features is not None and model.features is not None and params.feature_weight > 0:
        return None
    keep: BoolArray = own < params.gate_cost + bonus + ROUNDING_MARGIN
    return keep


def _or_zeros(values: FloatArray | None, n: int) -> FloatArray:
    return np.zeros(n) if values is None else values
