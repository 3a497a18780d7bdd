"""The associator contract (`associators/base.py`): constructing one only stores its validated
parameters (unknown names are an error, values are frozen), and `group` does the work."""

from __future__ import annotations

from typing import ClassVar

import numpy as np
import pytest
from pydantic import Field, ValidationError

from roadlink.association.associators.base import Associator, AssociatorParams, Progress
from roadlink.association.detections import Detections, IntArray


class EveryOtherParams(AssociatorParams):
    groups: int = Field(default=2, ge=1, description="How many groups to deal detections into.")


class EveryOther(Associator):
    """Deals the detections into `groups` groups in turn: enough to exercise the contract."""

    name: ClassVar[str] = "every-other"
    description: ClassVar[str] = "Deals detections into groups in turn."
    Params = EveryOtherParams
    params: EveryOtherParams

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        if progress:
            progress(1.0)
        return np.arange(len(detections), dtype=np.int64) % self.params.groups


def test_parameters_come_as_a_model_or_as_values_with_defaults():
    assert EveryOther().params == EveryOtherParams(groups=2)
    assert EveryOther(groups=3).params.groups == 3
    given = EveryOtherParams(groups=4)
    assert EveryOther(given).params is given


def test_unknown_or_invalid_parameters_are_refused_and_parameters_are_frozen():
    with pytest.raises(ValidationError, match="extra"):
        EveryOther(group_count=3)
    with pytest.raises(ValidationError, match="greater than or equal to 1"):
        EveryOther(groups=0)
    with pytest.raises(ValidationError, match="frozen"):
        EveryOther().params.groups = 5  # type: ignore[misc]


def test_the_parameters_schema_is_the_params_json_schema():
    schema = EveryOther.parameters_schema()
    assert schema == EveryOtherParams.model_json_schema()
    assert schema["properties"]["groups"]["minimum"] == 1
    assert schema["additionalProperties"] is False


def test_constructing_does_no_work_and_group_does():
    associator = EveryOther(groups=3)
    # Until `group` runs, nothing is fitted: no effective parameters, no link confidence.
    assert associator.effective_params is None and associator.link_confidence is None
    assert associator.needs_labels is False
    d = Detections.from_columns([0.0, 0.0, 100.0, 100.0], [20.0] * 4, [0.0, 1.0, 5.0, 6.0])
    seen: list[float] = []
    assert associator.group(d, seen.append).tolist() == [0, 1, 2, 0]
    assert seen == [1.0]


def test_an_associator_must_implement_group():
    class Unfinished(Associator):
        name: ClassVar[str] = "unfinished"
        description: ClassVar[str] = "No group."
        Params = EveryOtherParams

    with pytest.raises(TypeError, match="abstract"):
        Unfinished()  # type: ignore[abstract]
