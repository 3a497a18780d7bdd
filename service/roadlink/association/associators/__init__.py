"""The registry of associators, keyed by their stable names."""

from __future__ import annotations

from roadlink.association.associators.assignment import AssignmentAssociator
from roadlink.association.associators.base import (
    AssociationError,
    Associator,
    AssociatorParams,
    Progress,
)
from roadlink.association.associators.kmeans import KMeansAssociator, KMeansPlusPlusAssociator
from roadlink.association.associators.svm import LinearSVMAssociator, QuadraticSVMAssociator

ASSOCIATORS: dict[str, type[Associator]] = {
    cls.name: cls
    for cls in (
        AssignmentAssociator,
        KMeansAssociator,
        KMeansPlusPlusAssociator,
        LinearSVMAssociator,
        QuadraticSVMAssociator,
    )
}

DEFAULT_ASSOCIATOR = "assignment"


def get_associator_class(name: str) -> type[Associator]:
    """The associator registered under `name`; AssociationError naming the known ones if none."""
    try:
        return ASSOCIATORS[name]
    except KeyError:
        known = ", ".join(sorted(ASSOCIATORS))
        raise AssociationError(f"unknown associator '{name}'; known: {known}") from None


__all__ = [
    "ASSOCIATORS",
    "DEFAULT_ASSOCIATOR",
    "AssociationError",
    "Associator",
    "AssociatorParams",
    "Progress",
    "get_associator_class",
]
