"""How sure each link is: the approximate posterior probability that a link joins one vehicle.

At every sensor boundary the tracks are cut into prefixes and suffixes, as the re-pairing sweep
cuts them (`refine`), and every plausible way of joining them again competes with the joins the
tracks made. Each matching of pieces is weighted by its likelihood, exp(-cost / 2) per join and
exp(-gate / 4) per piece left alone (the costs of linking). A join's probability is the share of
that weight held by the matchings that contain it (`matching.chosen_marginals`). The re-pairing
sweep judges the links it keeps as it goes; `link_confidence` judges a set of tracks on its own.
`min_confidence` then cuts the links less sure than it (`cut_weak_links`).
"""

from __future__ import annotations

import numpy as np

from roadlink.association.associators.assignment.model import SegmentModel
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.refine import refine_boundaries
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.associators.assignment.tracks import successors, tracks_from_links
from roadlink.association.detections import FloatArray, IntArray


def link_confidence(
    s: Sensors, model: SegmentModel, params: AssignmentParams, track: IntArray
) -> FloatArray:
    """Per detection, the probability that the link into it from the previous detection of its
    track is right (NaN where it has no previous detection), judged by a sweep over the sensor
    boundaries that keeps every link (`refine_boundaries` with `relink=False`). The associator
    judges them in its last re-pairing sweep instead, when it has one."""
    confidence = np.full(track.size, np.nan)
    refine_boundaries(s, model, params, track, confidence, relink=False)
    return confidence


def cut_weak_links(
    s: Sensors, target: IntArray, confidence: FloatArray, min_confidence: float
) -> tuple[IntArray, FloatArray]:
    """The targets with every link less sure than `min_confidence` cut (each piece a target of
    its own, numbered anew), and the confidences of the links that remain (NaN elsewhere)."""
    kept = np.where(target >= 0, confidence, np.nan)
    if min_confidence <= 0.0:
        return target, kept
    _, prv = successors(s, target)
    weak = (prv >= 0) & (kept < min_confidence)
    prv[weak] = -1
    kept[weak] = np.nan
    return tracks_from_links(s, prv, target >= 0), kept
