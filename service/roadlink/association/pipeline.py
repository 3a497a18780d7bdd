"""One call from detections to a scored result: what the CLI and the service workers both run."""

from __future__ import annotations

import importlib
from collections.abc import Iterable, Mapping
from typing import Any

from pydantic import ValidationError

from roadlink.association.associators import (
    ASSOCIATORS,
    DEFAULT_ASSOCIATOR,
    AssociationError,
    AssociatorParams,
    Progress,
    get_associator_class,
)
from roadlink.association.detections import Detections
from roadlink.association.result import AssociationResult, build_result

# What the core may import beyond what every associator names (`imports_on_first_use`: what
# its first association of some size imports): the localisation's splines, and `assignment`'s
# dense solver, which only small blocks of links take.
_ALSO_DEFERRED = ("scipy.interpolate", "scipy.optimize")

DEFERRED_IMPORTS = tuple(
    sorted(
        {
            *_ALSO_DEFERRED,
            *(name for cls in ASSOCIATORS.values() for name in cls.imports_on_first_use),
        }
    )
)
"""What the core imports on first use, not with the core (scikit-learn: seconds to import;
scipy's solvers and splines: about 0.4 s; which the CLI need not pay for a command that does not
use them): a process that runs many jobs imports them up front (`import_deferred`), so that no
job's time limit counts them."""


def import_deferred() -> None:
    """Import `DEFERRED_IMPORTS` now."""
    for name in DEFERRED_IMPORTS:
        importlib.import_module(name)


def parse_params(associator: str, params: Mapping[str, Any] | None) -> AssociatorParams:
    """Validate an associator's parameters (strings such as CLI values are converted)."""
    cls = get_associator_class(associator)
    try:
        return cls.Params(**dict(params or {}))
    except ValidationError as exc:
        problems = "; ".join(
            f"parameter '{'.'.join(map(str, e['loc']))}': {e['msg']}" for e in exc.errors()
        )
        raise AssociationError(f"invalid parameters for '{associator}': {problems}") from None


def key_values(items: Iterable[str]) -> dict[str, str]:
    """`key=value` strings (the CLI's `--param`, a CSV batch's `param`) into a dict, whose values
    `parse_params` then converts. ValueError names the first item without an `=` or a key."""
    params: dict[str, str] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ValueError(f"a parameter is key=value, got '{item}'")
        params[key.strip()] = value.strip()
    return params


def associate(
    detections: Detections,
    associator: str = DEFAULT_ASSOCIATOR,
    params: Mapping[str, Any] | None = None,
    progress: Progress | None = None,
    *,
    scored: bool = True,
) -> AssociationResult:
    """Group `detections` into targets with the named associator, and score the grouping
    (unless not `scored`: a caller with something else to do meanwhile calls
    `AssociationResult.scored` itself).

    Unsupervised associators never see the labels, so scores cannot leak into the grouping.
    """
    cls = get_associator_class(associator)
    checked = parse_params(associator, params)
    if len(detections) == 0:
        raise AssociationError("there are no detections to associate")
    if detections.sensor_positions.size < 2:
        raise AssociationError(
            "the detections all come from one sensor position; association needs at least two"
        )
    visible = detections if cls.needs_labels else detections.without_labels()
    grouper = cls(checked)
    groups = grouper.group(visible, progress)
    effective = grouper.effective_params
    return build_result(
        detections,
        groups,
        associator,
        checked.model_dump(),
        None if effective is None else effective.model_dump(),
        grouper.link_confidence,
        scored=scored,
        warnings=grouper.warnings,
    )
