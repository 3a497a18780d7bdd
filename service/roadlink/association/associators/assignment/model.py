"""The segment model every link is costed with, and the heavy tails of its residuals."""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.assignment.arrays import filled
from roadlink.association.associators.assignment.features import FeatureModel
from roadlink.association.associators.assignment.params import (
    TAIL_EM_ITERATIONS,
    TAIL_EM_TOLERANCE,
    TAIL_MAX_SCALE,
    TAIL_MIN_SAMPLES,
    TAIL_MIN_SCALE,
    TAIL_REACH_POINTS,
    TAIL_SAMPLE,
    TAIL_WEIGHT_RANGE,
)
from roadlink.association.detections import FloatArray, IntArray

if TYPE_CHECKING:
    from roadlink.association.associators.assignment.ends import RoadEnds
    from roadlink.association.associators.assignment.pace import PaceModel

BoolArray = npt.NDArray[np.bool_]


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
        log_core, log_tail, log_norm, scale2 = _mixture_constants(self.weight, self.scale)
        # In place, in this order: -2 (logaddexp(log_core - r2 / 2, log_tail - r2 / 2 / s^2)
        # - log_norm), each step as written out once (the same numbers to the last bit).
        half = np.multiply(r2, 0.5, out=r2)
        tail = np.divide(half, scale2)
        np.subtract(log_tail, tail, out=tail)
        core = np.subtract(log_core, half, out=half)
        np.logaddexp(core, tail, out=core)
        core -= log_norm
        core *= -2.0
        return core

    def reach(self, budget: float) -> float:
        """The largest |r| whose cost stays within `budget` (the cost grows with |r|)."""
        return _reach(self.weight, self.scale, budget)

    def within(self, r: FloatArray, span: IntArray, miss_cost: float, gate: float) -> BoolArray:
        """Whether cost(r) + miss_cost * (span - 1) < gate, residual by residual, exactly as
        computed so; but only the residuals near the limit are costed. The cost grows with |r|
        (its slope in r^2 is at least min(1, 1 / scale^2)), so the |r| on a fine grid where it
        meets the limit (`_limits`) bound, with a margin far beyond rounding, the residuals that
        surely pass and those that surely fail."""
        size = np.abs(r)
        top = int(span.max(initial=0))
        sure = filled(top + 1, -np.inf)
        unsure = filled(top + 1, -np.inf)
        for k in range(1, top + 1):
            sure[k], unsure[k] = _limits(self.weight, self.scale, miss_cost * (k - 1), gate)
        keep = size < sure[span]
        near = (~keep & (size <= unsure[span])).nonzero()[0]
        if near.size:
            keep[near] = self.cost(r[near]) + miss_cost * (span[near] - 1) < gate
        return keep

    @classmethod
    def fit(cls, z: FloatArray, prior: Tails) -> Tails:
        """EM for the tail share and width of core-standardised residuals (the core fixed at 1,
        the tail at least TAIL_MIN_SCALE wide so it stays a tail)."""
        if z.size < TAIL_MIN_SAMPLES:
            return prior
        z2 = np.square(z[:: max(1, z.size // TAIL_SAMPLE)])  # an even sample pins the shape
        w, s = prior.weight, prior.scale
        weight_tolerance, scale_tolerance = TAIL_EM_TOLERANCE
        half = 0.5 * z2
        # The same numbers as written out plainly, in place: on a paper-size batch the dozen
        # numpy calls of each of a few dozen iterations are the work. The tail's half / s^2 is
        # kept while s stays (at TAIL_MIN_SCALE, mostly).
        core, tail = np.empty_like(half), np.empty_like(half)
        scaled, scaled_by = half / (s * s), s
        for _ in range(TAIL_EM_ITERATIONS):
            before = (w, s)
            np.subtract(np.log1p(-w), half, out=core)
            if s != scaled_by:
                scaled, scaled_by = half / (s * s), s
            np.subtract(np.log(w / s), scaled, out=tail)
            share = np.logaddexp(core, tail, out=core)
            np.subtract(tail, share, out=share)
            np.exp(share, out=share)
            total = float(np.add.reduce(share))  # share.sum(), without its Python wrapper
            w = min(max(total / z2.size, TAIL_WEIGHT_RANGE[0]), TAIL_WEIGHT_RANGE[1])
            s = math.sqrt(float(share.dot(z2)) / max(total, 1e-9))  # `@`'s BLAS dot, quicker
            s = min(max(s, TAIL_MIN_SCALE), TAIL_MAX_SCALE)
            if abs(w - before[0]) < weight_tolerance and abs(s - before[1]) < scale_tolerance:
                break
        return cls(w, s)


@functools.lru_cache(maxsize=256)
def _mixture_constants(weight: float, scale: float) -> tuple[float, float, float, float]:
    """What `Tails.cost` needs of the mixture: log(1 - w), log(w / s), log(1 - w + w / s), s^2."""
    return (
        float(np.log1p(-weight)),
        float(np.log(weight / scale)),
        float(np.log(1.0 - weight + weight / scale)),
        scale * scale,
    )


@functools.lru_cache(maxsize=256)
def _reach(weight: float, scale: float, budget: float) -> float:
    hi = np.sqrt(budget) * max(scale, 1.0)
    grid = np.linspace(0.0, hi, TAIL_REACH_POINTS)
    inside = grid[Tails(weight, scale).cost(grid) <= budget]
    return float(inside[-1]) if inside.size else 0.0


@functools.lru_cache(maxsize=1024)
def _limits(weight: float, scale: float, extra: float, gate: float) -> tuple[float, float]:
    """Around the largest |r| with cost(r) + extra < gate: every |r| below the first number
    passes, every |r| above the second fails, as `Tails.cost` computes them.

    On a grid of |r| from 0 to where the cost surely exceeds the budget (it is at least
    r^2 min(1, 1 / scale^2)), i is the last point that passes. The true cost rises by at least
    max(budget, 1) / 512^2 from one point to the next, far beyond the rounding of its computed
    value (~1e-13), so every |r| below point i - 1 passes and every |r| above point i + 2 fails.
    """
    budget = max(gate - extra, 1.0)
    hi = 1.01 * np.sqrt(budget) * max(scale, 1.0)
    grid = np.linspace(0.0, hi, TAIL_REACH_POINTS)
    passes = np.flatnonzero(Tails(weight, scale).cost(grid) + extra < gate)
    i = int(passes[-1]) if passes.size else -1
    sure = float(grid[i - 1]) if i >= 1 else -np.inf
    unsure = float(grid[i + 2]) if i + 2 < grid.size else np.inf
    return sure, unsure


@dataclass
class SegmentModel:
    """Learned behaviour of the road between sensor p and sensor p + span, for every p and span.

    Arrays are indexed [p, span] (span 0 unused): log of the travel-time bias over the kinematic
    prediction, the skew of that prediction, the bias's spread, mean log speed ratio, and its
    spread. A link a -> b is predicted to take `exp(log_bias) * dx * ((1 - skew) / v_a +
    skew / v_b)` (`sensors.travel_time`): skew 0.5 weighs both ends' speeds alike (the
    kinematic prediction); where vehicles brake or accelerate at one place, near one end, that
    end's speed says less about the travel time and the learned skew moves away from it. The
    spread of a track's speed about its own pace is one number for the road, as are the tails
    of the three residuals. Where detectors report lane, length or class, `features` is what
    they say (`features.FeatureModel`). Once learned from tracks, `pace` is how a track's pace,
    read from its travel times, carries from one link to the next (`pace.PaceModel`).
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
    features: FeatureModel | None = None
    pace: PaceModel | None = None
    ends: RoadEnds | None = None

    @property
    def max_span(self) -> int:
        return int(self.log_bias.shape[1]) - 1

    def copy(self) -> SegmentModel:
        """A copy whose arrays can be changed without changing this one."""
        return SegmentModel(
            self.log_bias.copy(),
            self.skew.copy(),
            self.time_spread.copy(),
            self.log_speed_ratio.copy(),
            self.speed_spread.copy(),
            self.preferred_speed_spread,
            self.time_tails,
            self.speed_tails,
            self.level_tails,
            None if self.features is None else self.features.copy(),
            None if self.pace is None else self.pace.copy(),
            self.ends,
        )
