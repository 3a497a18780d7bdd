"""The associator contract: a named algorithm with declared, typed, defaulted parameters.

As in scikit-learn, constructing an associator only stores its parameters; all work happens in
`group`, which returns a group index per detection (-1 = unassigned, e.g. a false alarm).
"""

from __future__ import annotations

from abc import ABC, abstractmethod
from collections.abc import Callable
from typing import Any, ClassVar

from pydantic import BaseModel, ConfigDict

from roadlink.association.detections import Detections, FloatArray, IntArray

Progress = Callable[[float], None]
"""Called with the share of the work done, from 0 to 1."""


class AssociatorParams(BaseModel):
    """Base of every associator's parameters: unknown names are an error, not silently ignored,
    and so is an infinite or NaN number (the result's JSON could not hold it)."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class AssociationError(ValueError):
    """The associator cannot run on these detections with these parameters (a user error)."""


class Associator(ABC):
    """A way of grouping detections into targets."""

    name: ClassVar[str]
    description: ClassVar[str]
    needs_labels: ClassVar[bool] = False
    Params: ClassVar[type[AssociatorParams]]
    imports_on_first_use: ClassVar[tuple[str, ...]] = ()
    """Modules `group` imports when it first runs, kept out of `import roadlink` (which every
    command pays for): a one-shot command imports them on a thread while it reads its file,
    beside the parser, which lets go of the GIL; a worker imports every associator's up front
    (`pipeline.DEFERRED_IMPORTS`)."""
    heap_per_detection: ClassVar[int] = 0
    """About how many bytes of heap `group` allocates per detection beyond the detections, at
    scale, as measured (0: not measured): what a one-shot command touches beforehand, on a
    thread while it reads its file (`roadlink.cli.allocator`)."""
    effective_params: AssociatorParams | None = None
    """The parameters the last `group` ran with, for an associator that adapts the ones it was
    given to the detections (`assignment` holds those in time units to their time scale): set
    by `group`, like a fitted attribute in scikit-learn. None for an associator that runs with
    its parameters as given."""
    warnings: tuple[str, ...] = ()
    """What the last `group` found wrong with the detectors, for whoever keeps them (a sensor
    whose clock is off, one whose speeds read a factor off), set by `group`; also logged."""
    link_confidence: FloatArray | None = None
    """Per detection, the approximate probability that the link into it from the previous
    detection of its target is right (NaN for a target's first detection and for unassigned
    ones), set by `group` for an associator that builds its targets from links (`assignment`);
    None for one that does not (K-means and the SVMs group points, not links)."""

    def __init__(self, params: AssociatorParams | None = None, **values: Any) -> None:
        self.params = params if params is not None else self.Params(**values)

    @classmethod
    def parameters_schema(cls) -> dict[str, Any]:
        """JSON Schema of the parameters, for `GET /v1/associators` and the CLI's help."""
        return cls.Params.model_json_schema()

    @abstractmethod
    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        """Group index of every detection (-1 = unassigned)."""
