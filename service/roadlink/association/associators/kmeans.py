"""The paper's unsupervised associators: K-means (random centres) and K-means++ (D^2 seeding).

Both cluster the (velocity, time) points of the detections, time back-projected to the reference
sensor unless `backproject` is false (the paper's raw-data baseline), and take one cluster as one
target. Beyond the paper, `use_length` adds the measured vehicle length as a third coordinate
(`lengths`). The seeding is implemented here, as the paper states it; Lloyd's iterations are
scikit-learn's.
"""

from __future__ import annotations

import warnings
from typing import ClassVar

import numpy as np
from pydantic import Field
from sklearn.cluster import KMeans
from sklearn.exceptions import ConvergenceWarning

from roadlink.association.associators.base import Associator, AssociatorParams, Progress
from roadlink.association.associators.lengths import with_length
from roadlink.association.backprojection import backprojected_features
from roadlink.association.detections import Detections, FloatArray, IntArray

# With use_length, a metre of length counts as this many m/s of velocity (or seconds of
# back-projected time). On the paper's three presets with a 5 % length error (100 seeds), 3 was
# the one weight of 2, 3, 4, 5 that gained on all six preset x K-means pairs: less tells a car
# from a van too weakly, more lets the length error outweigh speed and time (10 already loses
# on small with K-means++, 30 loses 7 and 19 points there).
DEFAULT_LENGTH_WEIGHT = 3.0


class KMeansParams(AssociatorParams):
    n_targets: int | None = Field(
        default=None,
        ge=1,
        description="Number of targets (clusters). Default: estimated as the median number of "
        "detections per sensor.",
    )
    backproject: bool = Field(
        default=True,
        description="Cluster on time back-projected to the first sensor (the "
        "paper's pre-processing); false clusters the raw (velocity, timestamp) points.",
    )
    n_init: int = Field(
        default=1, ge=1, le=100, description="Independent restarts; the lowest-cost one is kept."
    )
    max_iter: int = Field(default=300, ge=1, le=10_000, description="Lloyd iterations at most.")
    seed: int = Field(default=0, ge=0, description="Seed of the random initial centres.")
    use_length: bool = Field(
        default=False,
        description="Also cluster on the measured vehicle length (beyond the paper); a missing "
        "length is imputed with the median of its sensor's measured lengths.",
    )
    length_weight: float = Field(
        default=DEFAULT_LENGTH_WEIGHT,
        gt=0,
        le=1000,
        description="With use_length: how far apart, in velocity units, two detections one "
        "length unit apart count (velocity and time are not rescaled).",
    )


def estimate_target_count(detections: Detections) -> int:
    """The typical number of detections per sensor: each target passes each sensor once."""
    counts = np.unique(detections.position, return_counts=True)[1]
    return max(1, round(float(np.median(counts))))


def random_centres(points: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
    """K distinct data points chosen uniformly: the paper's plain K-means start."""
    return points[rng.choice(points.shape[0], size=k, replace=False)]


def kmeanspp_centres(points: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
    """The paper's K-means++ seeding: first centre uniform, each next one drawn with probability
    D(x)^2 / sum D^2, D(x) being the distance from x to the nearest centre chosen so far."""
    centres = [points[rng.integers(points.shape[0])]]
    nearest_sq = np.sum((points - centres[0]) ** 2, axis=1)
    for _ in range(1, k):
        total = nearest_sq.sum()
        if total <= 0:  # every point coincides with a centre: any point will do
            index = int(rng.integers(points.shape[0]))
        else:
            index = int(rng.choice(points.shape[0], p=nearest_sq / total))
        centres.append(points[index])
        nearest_sq = np.minimum(nearest_sq, np.sum((points - points[index]) ** 2, axis=1))
    return np.asarray(centres)


class KMeansAssociator(Associator):
    name: ClassVar[str] = "kmeans"
    description: ClassVar[str] = (
        "The paper's K-means: Lloyd's algorithm from k data points chosen at random, in "
        "(velocity, back-projected time) space, with use_length the measured length too. Needs "
        "the number of targets (estimated if absent)."
    )
    Params = KMeansParams
    params: KMeansParams

    def _initial_centres(self, points: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
        return random_centres(points, k, rng)

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        p = self.params
        points = backprojected_features(detections, p.backproject)
        if p.use_length:
            points = with_length(points, detections, p.length_weight)
        k = min(p.n_targets or estimate_target_count(detections), points.shape[0])
        rng = np.random.default_rng(p.seed)
        best: KMeans | None = None
        for attempt in range(p.n_init):
            model = KMeans(
                n_clusters=k,
                init=self._initial_centres(points, k, rng),
                n_init=1,
                max_iter=p.max_iter,
                algorithm="lloyd",
            )
            with warnings.catch_warnings():
                # Coinciding points (e.g. constant speeds) leave a cluster empty: expected here.
                warnings.simplefilter("ignore", ConvergenceWarning)
                model.fit(points)
            if best is None or model.inertia_ < best.inertia_:
                best = model
            if progress:
                progress((attempt + 1) / p.n_init)
        assert best is not None
        return np.asarray(best.labels_, dtype=np.int64)


class KMeansPlusPlusAssociator(KMeansAssociator):
    name: ClassVar[str] = "kmeans++"
    description: ClassVar[str] = (
        "The paper's K-means++: K-means seeded by D^2 sampling (Arthur and Vassilvitskii), in "
        "(velocity, back-projected time) space, with use_length the measured length too. Needs "
        "the number of targets (estimated if absent)."
    )

    def _initial_centres(self, points: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
        return kmeanspp_centres(points, k, rng)
