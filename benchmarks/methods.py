"""The grouping methods a benchmark can time: every registered associator, and the peer tracker."""

from __future__ import annotations

from collections.abc import Callable

from roadlink.association.associators import ASSOCIATORS
from roadlink.association.detections import Detections, IntArray

STONESOUP_GNN = "stonesoup-gnn"
"""Stone Soup's GNN tracker (benchmarks.stonesoup_gnn), the peer roadlink is compared with."""


def stonesoup_available() -> bool:
    """Whether Stone Soup (the `bench` extra) is installed."""
    try:
        import stonesoup  # noqa: F401
    except ImportError:
        return False
    return True


def grouping_method(name: str) -> Callable[[Detections], IntArray]:
    """A function from (labelled) detections to groups, as the method would be used.

    Unsupervised associators and the tracker see the detections without labels; supervised ones
    see the labels, as `roadlink.association.pipeline.associate` arranges.
    """
    if name == STONESOUP_GNN:
        from benchmarks.stonesoup_gnn import track_groups

        return lambda detections: track_groups(detections.without_labels())
    cls = ASSOCIATORS[name]

    def group(detections: Detections) -> IntArray:
        visible = detections if cls.needs_labels else detections.without_labels()
        return cls().group(visible)

    return group
