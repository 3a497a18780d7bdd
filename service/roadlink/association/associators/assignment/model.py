"""The segment model every link is costed with, and the heavy tails of its residuals."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

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
from roadlink.association.detections import FloatArray


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
        w, s = self.weight, self.scale
        core = np.log1p(-w) - 0.5 * r2
        tail = np.log(w / s) - 0.5 * r2 / (s * s)
        return -2.0 * (np.logaddexp(core, tail) - np.log(1.0 - w + w / s))

    def reach(self, budget: float) -> float:
        """The largest |r| whose cost stays within `budget` (the cost grows with |r|)."""
        hi = np.sqrt(budget) * max(self.scale, 1.0)
        grid = np.linspace(0.0, hi, TAIL_REACH_POINTS)
        inside = grid[self.cost(grid) <= budget]
        return float(inside[-1]) if inside.size else 0.0

    @classmethod
    def fit(cls, z: FloatArray, prior: Tails) -> Tails:
        """EM for the tail share and width of core-standardised residuals (the core fixed at 1,
        the tail at least TAIL_MIN_SCALE wide so it stays a tail)."""
        if z.size < TAIL_MIN_SAMPLES:
            return prior
        z2 = np.square(z[:: max(1, z.size // TAIL_SAMPLE)])  # an even sample pins the shape
        w, s = prior.weight, prior.scale
        weight_tolerance, scale_tolerance = TAIL_EM_TOLERANCE
        for _ in range(TAIL_EM_ITERATIONS):
            before = (w, s)
            core = np.log1p(-w) - 0.5 * z2
            tail = np.log(w / s) - 0.5 * z2 / (s * s)
            share = np.exp(tail - np.logaddexp(core, tail))
            total = float(share.sum())
            w = float(np.clip(total / z2.size, TAIL_WEIGHT_RANGE[0], TAIL_WEIGHT_RANGE[1]))
            s = float(np.sqrt(float(share @ z2) / max(total, 1e-9)))
            s = min(max(s, TAIL_MIN_SCALE), TAIL_MAX_SCALE)
            if abs(w - before[0]) < weight_tolerance and abs(s - before[1]) < scale_tolerance:
                break
        return cls(w, s)


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
    they say (`features.FeatureModel`).
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
        )
