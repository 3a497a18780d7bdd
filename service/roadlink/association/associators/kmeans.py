"""The paper's unsupervised associators: K-means (random centres) and K-means++ (D^2 seeding).

Both cluster the (velocity, time) points of the detections, time back-projected to the reference
sensor unless `backproject` is false (the paper's raw-data baseline), and take one cluster as one
target. Beyond the paper, `use_length` adds the measured vehicle length as a third coordinate
(`lengths`). The seeding is implemented here, as the paper states it; Lloyd's iterations are
scikit-learn's, except where some detections have no length: there roadlink's own Lloyd leaves
a missing length out of that detection's distances (`partial_distance_lloyd`).
"""

from __future__ import annotations

import warnings
from typing import ClassVar

import numpy as np
import numpy.typing as npt
from pydantic import Field

from roadlink.association.associators.base import Associator, AssociatorParams, Progress
from roadlink.association.associators.lengths import observed_coordinates, with_length
from roadlink.association.backprojection import backprojected_features
from roadlink.association.detections import Detections, FloatArray, IntArray

# With use_length, a metre of length counts as this many m/s of velocity (or seconds of
# back-projected time). On the paper's three presets with a 5 % length error (100 seeds), of
# 2, 3, 4 and 5, only 3 and 5 gained on all six preset x K-means pairs (2.2 points on average,
# both); far less tells a car from a van too weakly (1 gains 0.1-1.3 points on small), far more
# lets the length error outweigh speed and time (10 loses 2.9 on small with K-means++, 30 loses
# 7 and 19).
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
        description="Also cluster on the measured vehicle length (beyond the paper); a "
        "detection without one is clustered on its velocity and time alone.",
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
    imports_on_first_use: ClassVar[tuple[str, ...]] = ("sklearn.cluster",)
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
        observed = None
        if p.use_length:
            points = with_length(points, detections, p.length_weight)
            observed = observed_coordinates(points, detections)
        k = min(p.n_targets or estimate_target_count(detections), points.shape[0])
        rng = np.random.default_rng(p.seed)
        best: tuple[float, IntArray] | None = None
        for attempt in range(p.n_init):
            init = self._initial_centres(points, k, rng)
            if observed is None:
                cost, labels = lloyd(points, init, p.max_iter)
            else:
                cost, labels = partial_distance_lloyd(points, observed, init, p.max_iter)
            if best is None or cost < best[0]:
                best = (cost, labels)
            if progress:
                progress((attempt + 1) / p.n_init)
        assert best is not None
        return best[1]


def lloyd(points: FloatArray, init: FloatArray, max_iter: int) -> tuple[float, IntArray]:
    """scikit-learn's Lloyd iterations from the given centres: (inertia, cluster of each point)."""
    # Imported here: scikit-learn takes seconds to import, which a process that runs another
    # associator (or none) need not pay.
    from sklearn.cluster import KMeans
    from sklearn.exceptions import ConvergenceWarning

    model = KMeans(
        n_clusters=init.shape[0], init=init, n_init=1, max_iter=max_iter, algorithm="lloyd"
    )
    with warnings.catch_warnings():
        # Coinciding points (e.g. constant speeds) leave a cluster empty: expected here.
        warnings.simplefilter("ignore", ConvergenceWarning)
        model.fit(points)
    return float(model.inertia_), np.asarray(model.labels_, dtype=np.int64)


# Rows x centres per block of the distance computation: bounds its memory (8 bytes each).
DISTANCE_BLOCK = 1 << 22


def partial_distance_lloyd(
    points: FloatArray, observed: npt.NDArray[np.bool_], init: FloatArray, max_iter: int
) -> tuple[float, IntArray]:
    """Lloyd's iterations where some points lack some coordinates (`observed` is False there):
    a distance is summed over the point's observed coordinates only, and a centre's coordinate
    is the mean of the points that observed it (it keeps its value while none does). Unlike an
    imputed value, a missing coordinate then pulls a point towards no centre. With every
    coordinate observed this is plain Lloyd."""
    centres = init.copy()
    weight = observed.astype(np.float64)
    labels, cost = _nearest_observed(points, weight, centres)
    for _ in range(max_iter):
        moved = _observed_means(points, weight, labels, centres)
        if np.array_equal(moved, centres):
            break
        centres = moved
        labels, cost = _nearest_observed(points, weight, centres)
    return cost, labels


def _nearest_observed(
    points: FloatArray, weight: FloatArray, centres: FloatArray
) -> tuple[IntArray, float]:
    """Each point's nearest centre over its observed coordinates, and the summed distances."""
    labels = np.empty(points.shape[0], dtype=np.int64)
    cost = 0.0
    rows = max(1, DISTANCE_BLOCK // centres.shape[0])
    for start in range(0, points.shape[0], rows):
        x, w = points[start : start + rows], weight[start : start + rows]
        # sum_d w (x - c)^2 = sum_d w x^2 - 2 sum_d w x c + sum_d w c^2, as matrix products.
        squared = (w * x**2).sum(axis=1)[:, None] - 2 * (w * x) @ centres.T + w @ (centres**2).T
        nearest = squared.argmin(axis=1)
        labels[start : start + rows] = nearest
        cost += float(np.maximum(squared[np.arange(nearest.size), nearest], 0.0).sum())
    return labels, cost


def _observed_means(
    points: FloatArray, weight: FloatArray, labels: IntArray, centres: FloatArray
) -> FloatArray:
    """Each cluster's mean of every coordinate over the points that observed it."""
    moved = centres.copy()
    for dim in range(points.shape[1]):
        count = np.bincount(labels, weights=weight[:, dim], minlength=centres.shape[0])
        total = np.bincount(
            labels, weights=weight[:, dim] * points[:, dim], minlength=centres.shape[0]
        )
        seen = count > 0
        moved[seen, dim] = total[seen] / count[seen]
    return moved


class KMeansPlusPlusAssociator(KMeansAssociator):
    name: ClassVar[str] = "kmeans++"
    description: ClassVar[str] = (
        "The paper's K-means++: K-means seeded by D^2 sampling (Arthur and Vassilvitskii), in "
        "(velocity, back-projected time) space, with use_length the measured length too. Needs "
        "the number of targets (estimated if absent)."
    )

    def _initial_centres(self, points: FloatArray, k: int, rng: np.random.Generator) -> FloatArray:
        return kmeanspp_centres(points, k, rng)
