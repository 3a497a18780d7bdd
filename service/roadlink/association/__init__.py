"""The association core: pure numpy / scipy / scikit-learn; knows nothing of HTTP or SQL."""

from roadlink.association.detections import CLUTTER, DetectionError, Detections, Problem
from roadlink.association.pipeline import associate, key_values, parse_params
from roadlink.association.result import AssociationResult

__all__ = [
    "CLUTTER",
    "AssociationResult",
    "DetectionError",
    "Detections",
    "Problem",
    "associate",
    "key_values",
    "parse_params",
]
