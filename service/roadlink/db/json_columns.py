"""The typed values of the schema's JSON columns: a job's selection (batches, or a time window)
and a deployment's declared sensors.

Code builds and reads these types; the column types below store exactly the JSON the columns
have always held, so rows written before read back as they are (no migration).
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

from sqlalchemy import JSON, Dialect, TypeDecorator


@dataclass(frozen=True)
class BatchSelection:
    """A job over these batches of one deployment, in the order asked for."""

    batch_ids: tuple[uuid.UUID, ...]

    @classmethod
    def of(cls, batch_ids: Iterable[uuid.UUID]) -> BatchSelection:
        """The batches, a batch named twice taken once."""
        return cls(tuple(dict.fromkeys(batch_ids)))

    def to_json(self) -> dict[str, Any]:
        return {"batch_ids": [str(b) for b in self.batch_ids]}


@dataclass(frozen=True)
class WindowSelection:
    """A job over a deployment's detections with start <= timestamp < end; an end that is None
    is left open."""

    start: float | None
    end: float | None

    def to_json(self) -> dict[str, Any]:
        return {"start": self.start, "end": self.end}


Selection = BatchSelection | WindowSelection


def selection_from_json(stored: dict[str, Any]) -> Selection:
    """The selection `to_json` stored."""
    if "batch_ids" in stored:
        return BatchSelection(tuple(uuid.UUID(str(b)) for b in stored["batch_ids"]))
    return WindowSelection(stored.get("start"), stored.get("end"))


class SelectionType(TypeDecorator[Selection]):
    """A job's selection: stored as its JSON, read back as a `Selection`."""

    impl = JSON
    cache_ok = True

    def process_bind_param(self, value: Selection | None, dialect: Dialect) -> Any:
        return None if value is None else value.to_json()

    def process_result_value(self, value: Any, dialect: Dialect) -> Selection | None:
        return None if value is None else selection_from_json(value)


@dataclass(frozen=True)
class Sensor:
    """A declared sensor of a deployment: the id its detections use, and where it is."""

    sensor_id: str
    position: float


class SensorsType(TypeDecorator[list[Sensor]]):
    """A deployment's declared sensors, in road order: stored as
    [{"sensor_id": ..., "position": ...}], read back as `Sensor`s."""

    impl = JSON
    cache_ok = True

    def process_bind_param(self, value: list[Sensor] | None, dialect: Dialect) -> Any:
        if value is None:
            return None
        return [{"sensor_id": s.sensor_id, "position": s.position} for s in value]

    def process_result_value(self, value: Any, dialect: Dialect) -> list[Sensor] | None:
        if value is None:
            return None
        return [Sensor(str(s["sensor_id"]), float(s["position"])) for s in value]
