"""What requests ask of the services, as plain values (the API's schemas are not needed to
call a service)."""

from __future__ import annotations

import uuid
from dataclasses import dataclass, field
from typing import Any


@dataclass(frozen=True)
class Associate:
    """An association asked for: `roadlink.services.jobs.AssociationAsked`."""

    associator: str = "kmeans"
    params: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Job(Associate):
    """A job asked for: `roadlink.services.jobs.JobAsked`."""

    batch_id: uuid.UUID | None = None
    batch_ids: list[uuid.UUID] | None = None
    deployment_id: uuid.UUID | None = None
    start: float | None = None
    end: float | None = None
