"""The measured vehicle length as one more feature of the paper's associators (`use_length`).

The paper's detector reports only (position, velocity, timestamp); a loop or a radar that also
measures the vehicle's length tells a truck from a car, which velocity and back-projected time
alone cannot when the two drive alike. A length stays with its vehicle along the road, so unlike
velocity (which drifts) it needs no back-projection.

Not every detector measures length, nor every detection of one that does. K-means leaves a
missing length out of that detection's distances (`observed_coordinates`, and the K-means
module's `partial_distance_lloyd`): it pulls the detection towards no centre. Its seeding and
the SVMs need every coordinate, so there a missing length is imputed with the median of the
lengths its sensor measured (a sensor's own calibration stays its own), or, at a sensor that
measured none, with the median of all measured lengths: a typical vehicle. Imputing is a guess
that costs: with 30 % of the lengths missing at random, the quadratic SVM lost a few points with
`use_length` (docs/simulated-features.md); K-means, which does not impute in its iterations,
lost at most 1.2 points and gained up to 2.4 (means over 100 seeds of each paper preset).
"""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roadlink.association.associators.base import AssociationError
from roadlink.association.detections import Detections, FloatArray


def imputed_lengths(detections: Detections) -> FloatArray:
    """Every detection's measured length, missing ones imputed (see the module's doc).
    AssociationError when no detection has a measured length."""
    measured = detections.has_length
    if not measured.any():
        raise AssociationError(
            "use_length needs measured vehicle lengths, and no detection has one "
            "(the 'length' field or CSV column)"
        )
    lengths = detections.length.copy()
    overall = float(np.median(lengths[measured]))
    for position in np.unique(detections.position[~measured]):
        at = detections.position == position
        known = lengths[at & measured]
        lengths[at & ~measured] = float(np.median(known)) if known.size else overall
    return lengths


def with_length(points: FloatArray, detections: Detections, weight: float = 1.0) -> FloatArray:
    """The feature matrix `points` with each detection's (imputed) length, times `weight`, as
    its last column."""
    return np.column_stack([points, weight * imputed_lengths(detections)])


def observed_coordinates(
    points: FloatArray, detections: Detections
) -> npt.NDArray[np.bool_] | None:
    """For `with_length`'s points, which coordinates each detection measured (its length is the
    last); None when every detection measured its length."""
    measured = detections.has_length
    if measured.all():
        return None
    observed = np.ones(points.shape, dtype=bool)
    observed[:, -1] = measured
    return observed
