"""The detector features (lane, vehicle length, vehicle class) as evidence for a link.

A link a -> b gains a term -2 log(likelihood ratio) per feature that both ends report: how much
more likely b's value is if b is a's vehicle than if it is any vehicle at b's sensor.

- **Length** is a constant of the vehicle, read with a measurement error. A track piece's lengths
  are averaged (in log, so the error is relative), and the two pieces' means are compared: under
  "same vehicle" they differ by the measurement error alone; under "another vehicle" the far
  piece's mean is a draw from the lengths its sensor saw. A share `LENGTH_OUTLIER` of readings
  is allowed to be anything (a loop that misreads a vehicle pulling over it, a false alarm): it
  caps what one bad reading can cost.
- **Lane** is a soft cue: vehicles change lanes, most near merges and lane drops. Each segment
  learns its own lane transition matrix, so a lane drop (three lanes into one) makes lane carry
  no evidence there rather than forbid the link.
- **Class** is a constant of the vehicle, read with classification errors: one confusion matrix
  for the road.

Everything is learned from the confident tracks, as the travel times are (`learning`), from
priors that assume little. A detection that does not report a feature adds no term for it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from roadlink.association.associators.assignment.robust import centre_and_spread
from roadlink.association.detections import NO_LANE, Detections, FloatArray, IntArray

# A detection whose class is not reported (`SensorFeatures.vehicle_class`).
NO_CLASS = -1
# The most classes a batch's vocabulary is read with (the commonest; see `SensorFeatures.of`).
MAX_CLASSES = 64
# Before any track is learned: a relative length error of 10 % (a loop's is 5-10 %).
PRIOR_LENGTH_SPREAD = 0.10
# A measured spread below this is taken as this: lengths are never exact.
MIN_LENGTH_SPREAD = 0.01
# The share of length readings that may be anything (see the module's docstring).
LENGTH_OUTLIER = 0.05
# Background density of log lengths at a sensor: a histogram of this bin width, smoothed with a
# kernel this wide (the readings already carry their error; this only fills the gaps).
LENGTH_BIN = 0.01
LENGTH_KERNEL = 0.03
# Before learning, a vehicle stays in its lane (or reports its class) with this probability;
# otherwise its lane (class) at b is a draw from those seen at b's sensor.
PRIOR_SAME_LANE = 0.5
PRIOR_SAME_CLASS = 0.9
# The priors weigh as this many links in the learned matrices (a row's pseudo-counts).
PRIOR_LINKS = 20.0
# No probability in a matrix or background is taken below this: one odd value never forbids.
MIN_PROBABILITY = 1e-3


@dataclass
class SensorFeatures:
    """The features of every detection, as the associator uses them."""

    log_length: FloatArray  # NaN where not measured
    lane: IntArray  # NO_LANE where not reported
    vehicle_class: IntArray  # index into the batch's classes, NO_CLASS where not reported
    n_lanes: int
    n_classes: int

    @classmethod
    def of(cls, detections: Detections) -> SensorFeatures | None:
        """The features of the detections, or None when none reports any (then every cost is
        exactly what it was before features existed)."""
        if not detections.features:
            return None
        reported = detections.has_vehicle_class
        names, coded, counts = np.unique(
            detections.vehicle_class[reported].astype(str), return_inverse=True, return_counts=True
        )
        vehicle_class = np.full(len(detections), NO_CLASS, dtype=np.int64)
        vehicle_class[reported] = coded
        if names.size > MAX_CLASSES:
            # A class vocabulary is a handful of words; thousands (a free-text field) would make
            # the confusion matrix their square. The commonest are kept, the rest unreported.
            kept = np.sort(np.argsort(-counts, kind="stable")[:MAX_CLASSES])
            code = np.full(names.size, NO_CLASS, dtype=np.int64)
            code[kept] = np.arange(kept.size)
            vehicle_class[reported] = code[coded]
            names = names[kept]
        return cls(
            np.log(detections.length),
            detections.lane.astype(np.int64),
            vehicle_class,
            int(detections.lane.max()) + 1,
            int(names.size),
        )

    def has_length(self) -> bool:
        return bool(np.isfinite(self.log_length).any())

    def has_lane(self) -> bool:
        return bool((self.lane != NO_LANE).any())


@dataclass
class FeatureModel:
    """What the features say, learned: the length error, each segment's lane transitions (indexed
    [p, span, lane at p, lane at p + span]), the class confusion matrix, and what each sensor
    sees (its lanes' and classes' shares, a density of its log lengths)."""

    length_spread: float
    lane_transition: FloatArray
    class_confusion: FloatArray
    lane_share: FloatArray  # [sensor, lane]
    class_share: FloatArray  # [sensor, class]
    length_grid: FloatArray  # bin centres of the log-length densities
    length_density: FloatArray  # [sensor, bin]

    @property
    def max_span(self) -> int:
        return int(self.lane_transition.shape[1]) - 1

    def copy(self) -> FeatureModel:
        return FeatureModel(
            self.length_spread,
            self.lane_transition.copy(),
            self.class_confusion.copy(),
            self.lane_share,
            self.class_share,
            self.length_grid,
            self.length_density,
        )


def prior_features(
    f: SensorFeatures, sensor: IntArray, n_sensors: int, max_span: int
) -> FeatureModel:
    """The features' model before any track is known."""
    lane_share = _shares(f.lane, sensor, n_sensors, f.n_lanes)
    class_share = _shares(f.vehicle_class, sensor, n_sensors, f.n_classes)
    lane_transition = np.zeros((n_sensors, max_span + 1, f.n_lanes, f.n_lanes))
    for p in range(n_sensors):
        for span in range(1, max_span + 1):
            q = min(p + span, n_sensors - 1)
            lane_transition[p, span] = _stay_or_draw(lane_share[q], PRIOR_SAME_LANE)
    pooled_class = class_share.mean(axis=0) if n_sensors else np.ones(f.n_classes)
    grid, density = _length_densities(f.log_length, sensor, n_sensors)
    return FeatureModel(
        PRIOR_LENGTH_SPREAD,
        lane_transition,
        _stay_or_draw(pooled_class, PRIOR_SAME_CLASS),
        lane_share,
        class_share,
        grid,
        density,
    )


def learn_features(
    f: SensorFeatures,
    sensor: IntArray,
    prior: FeatureModel,
    links: list[tuple[IntArray, IntArray]],
) -> FeatureModel:
    """The model from the confident tracks' links (`links`: a -> b pairs, one array pair per span,
    any order): the length error from the links' length differences; lane transitions per
    segment and the class confusion as counts on top of the prior's pseudo-counts."""
    model = prior.copy()
    if not links:
        return model
    a = np.concatenate([pair[0] for pair in links])
    b = np.concatenate([pair[1] for pair in links])
    difference = f.log_length[b] - f.log_length[a]
    difference = difference[np.isfinite(difference)]
    if difference.size >= PRIOR_LINKS:
        # Each end carries its own error: the difference spreads sqrt(2) times as wide.
        spread = centre_and_spread(difference)[1] / np.sqrt(2.0)
        model.length_spread = max(float(spread), MIN_LENGTH_SPREAD)
    p, span = sensor[a], sensor[b] - sensor[a]
    both = (f.lane[a] != NO_LANE) & (f.lane[b] != NO_LANE) & (span <= model.max_span)
    counts = PRIOR_LINKS * prior.lane_transition
    np.add.at(counts, (p[both], span[both], f.lane[a][both], f.lane[b][both]), 1.0)
    model.lane_transition = _rows_normalised(counts)
    both = (f.vehicle_class[a] >= 0) & (f.vehicle_class[b] >= 0)
    confusion = PRIOR_LINKS * prior.class_confusion
    np.add.at(confusion, (f.vehicle_class[a][both], f.vehicle_class[b][both]), 1.0)
    model.class_confusion = _rows_normalised(confusion)
    return model


def feature_cost(
    f: SensorFeatures,
    model: FeatureModel,
    sensor: IntArray,
    a: IntArray,
    b: IntArray,
    lengths: tuple[FloatArray, FloatArray, FloatArray, FloatArray],
) -> FloatArray:
    """-2 log likelihood ratio of every link a -> b from the features both ends report.

    `lengths` holds the mean log length of the piece ending in a and its number of readings,
    then the same of the piece starting with b (0 readings: no length term)."""
    cost = np.zeros(a.size)
    before_mean, before_count, after_mean, after_count = lengths
    measured = (before_count > 0) & (after_count > 0)
    if measured.any():
        cost[measured] = _length_cost(
            model,
            sensor[b[measured]],
            before_mean[measured],
            before_count[measured],
            after_mean[measured],
            after_count[measured],
        )
    p, q = sensor[a], sensor[b]
    lane_a, lane_b = f.lane[a], f.lane[b]
    both = (lane_a != NO_LANE) & (lane_b != NO_LANE) & (q - p <= model.max_span)
    if both.any():
        same = model.lane_transition[p[both], (q - p)[both], lane_a[both], lane_b[both]]
        cost[both] -= 2.0 * np.log(same / model.lane_share[q[both], lane_b[both]])
    class_a, class_b = f.vehicle_class[a], f.vehicle_class[b]
    both = (class_a >= 0) & (class_b >= 0)
    if both.any():
        same = model.class_confusion[class_a[both], class_b[both]]
        cost[both] -= 2.0 * np.log(same / model.class_share[q[both], class_b[both]])
    return cost


def _length_cost(
    model: FeatureModel,
    q: IntArray,
    before_mean: FloatArray,
    before_count: FloatArray,
    after_mean: FloatArray,
    after_count: FloatArray,
) -> FloatArray:
    variance = model.length_spread**2 * (1.0 / before_count + 1.0 / after_count)
    difference = after_mean - before_mean
    log_same = -0.5 * difference**2 / variance - 0.5 * np.log(2.0 * np.pi * variance)
    log_other = np.log(length_density_at(model, q, after_mean))
    ratio = np.logaddexp(np.log1p(-LENGTH_OUTLIER) + log_same - log_other, np.log(LENGTH_OUTLIER))
    return np.asarray(-2.0 * ratio, dtype=np.float64)


def length_density_at(
    model: FeatureModel, sensor: IntArray | int, log_length: FloatArray
) -> FloatArray:
    """How densely `sensor`'s log lengths lie at each of `log_length` (the learned kernel
    density, read at the nearest bin of its grid)."""
    bins = np.clip(
        np.round((log_length - model.length_grid[0]) / LENGTH_BIN).astype(np.int64),
        0,
        model.length_grid.size - 1,
    )
    density: FloatArray = model.length_density[sensor, bins]
    return density


def _shares(values: IntArray, sensor: IntArray, n_sensors: int, n_values: int) -> FloatArray:
    """Each sensor's share of every value (lane, class), never below MIN_PROBABILITY."""
    counts = np.zeros((n_sensors, max(n_values, 1)))
    reported = values >= 0
    np.add.at(counts, (sensor[reported], values[reported]), 1.0)
    return _rows_normalised(counts + MIN_PROBABILITY * np.maximum(counts.sum(1, keepdims=True), 1))


def _stay_or_draw(share: FloatArray, stay: float) -> FloatArray:
    """A transition matrix that keeps the value with probability `stay`, else draws one from
    `share` (rows: the value before; a value absent after is drawn from `share` alone)."""
    n = share.shape[-1]
    present = share > 2 * MIN_PROBABILITY
    matrix = np.tile((1.0 - stay) * share, (n, 1)) + stay * np.diag(present.astype(float))
    matrix[~present] = share
    return _rows_normalised(matrix)


def _rows_normalised(counts: FloatArray) -> FloatArray:
    floored = np.maximum(counts, MIN_PROBABILITY * counts.sum(-1, keepdims=True) + 1e-12)
    return np.asarray(floored / floored.sum(-1, keepdims=True), dtype=np.float64)


def _length_densities(
    log_length: FloatArray, sensor: IntArray, n_sensors: int
) -> tuple[FloatArray, FloatArray]:
    """Per sensor, the density of its log lengths on a grid of LENGTH_BIN: a kernel density
    estimate (LENGTH_KERNEL), mixed with a little of the pooled
    density so that no reading is impossible anywhere."""
    measured = np.isfinite(log_length)
    if not measured.any():
        return np.zeros(1), np.ones((n_sensors, 1))
    spread = LENGTH_KERNEL
    low = float(log_length[measured].min()) - 4 * spread
    high = float(log_length[measured].max()) + 4 * spread
    grid = np.arange(low, high + LENGTH_BIN, LENGTH_BIN)
    counts = np.zeros((n_sensors, grid.size))
    bins = np.clip(
        np.round((log_length[measured] - low) / LENGTH_BIN).astype(np.int64), 0, grid.size - 1
    )
    np.add.at(counts, (sensor[measured], bins), 1.0)
    offsets = np.arange(-4 * spread, 4 * spread + LENGTH_BIN, LENGTH_BIN)
    kernel = np.exp(-0.5 * (offsets / spread) ** 2)
    smooth = np.array([np.convolve(row, kernel, mode="same") for row in counts])
    pooled = smooth.sum(0, keepdims=True)
    density = smooth / np.maximum(smooth.sum(1, keepdims=True), 1e-12)
    density = 0.9 * density + 0.1 * pooled / pooled.sum()
    # Probability per bin to density per unit of log length.
    return grid, np.maximum(density / LENGTH_BIN, MIN_PROBABILITY)
