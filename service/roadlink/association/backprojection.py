"""The paper's pre-processing: map every detection's time to the reference sensor S1, and back.

A target seen at sensor n (position R_n) at time T with velocity V would, had it kept that velocity,
have passed S1 at T' = T - (R_n - R_1) / V (the paper's equation for T'). Detections of one target
then gather near one (V, T') point, which is what makes them clusterable.
"""

from __future__ import annotations

import numpy as np

from roadlink.association.detections import Detections, FloatArray


def backproject_times(
    position: FloatArray, velocity: FloatArray, timestamp: FloatArray, reference_position: float
) -> FloatArray:
    """T' = T - (R_n - R_1) / V: each detection's estimated passing time at the reference sensor."""
    return timestamp - (position - reference_position) / velocity


def recover_times(
    position: FloatArray, velocity: FloatArray, backprojected: FloatArray, reference_position: float
) -> FloatArray:
    """The inverse mapping, T = T' + (R_n - R_1) / V: the original passing times."""
    return backprojected + (position - reference_position) / velocity


def backprojected_features(detections: Detections, backproject: bool = True) -> FloatArray:
    """The (velocity, time) feature matrix the paper clusters: time back-projected to S1 or raw."""
    times = (
        backproject_times(
            detections.position,
            detections.velocity,
            detections.timestamp,
            detections.reference_position,
        )
        if backproject
        else detections.timestamp
    )
    return np.column_stack([detections.velocity, times])
