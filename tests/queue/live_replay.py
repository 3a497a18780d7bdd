"""Replaying detections into a live association: per-sensor batches in time order, stored
through the service (so the live data clock advances as it does for an upload)."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import orjson
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association.detections import Detections
from roadlink.association.scores import Metrics, score_grouping
from roadlink.db.engine import transaction
from roadlink.db.models import LiveVehicle
from roadlink.services import live
from roadlink.services.batches import ParsedBatch, store_batch
from roadlink.settings import Settings


@dataclass(frozen=True)
class Asked:
    associator: str = "assignment"
    params: dict[str, Any] = field(default_factory=dict)


def per_sensor_batches(d: Detections, period: float) -> Iterator[Detections]:
    """One batch per sensor and `period` seconds, in the order a gateway per sensor posts them:
    by the end of their period, then by sensor."""
    bucket = np.floor(d.timestamp / period).astype(np.int64)
    keys = sorted({(int(b), str(s)) for b, s in zip(bucket, d.sensor_id, strict=True)})
    for b, s in keys:
        members = np.flatnonzero((bucket == b) & (d.sensor_id == s))
        yield d.take(members[np.argsort(d.timestamp[members], kind="stable")])


def store(
    sessions: sessionmaker[Session], settings: Settings, deployment: uuid.UUID, d: Detections
) -> None:
    with transaction(sessions) as session:
        store_batch(
            session,
            settings=settings,
            deployment_id=deployment,
            batch=ParsedBatch(d, "json", None),
        )


def start(
    sessions: sessionmaker[Session], deployment: uuid.UUID, lateness: float, **params: Any
) -> None:
    with sessions() as session:
        live.start_live(
            session, deployment_id=deployment, asked=Asked(params=params), lateness=lateness
        )


def flush(sessions: sessionmaker[Session], deployment: uuid.UUID) -> None:
    with sessions() as session:
        live.flush_live(session, deployment_id=deployment)


def published(sessions: sessionmaker[Session], deployment: uuid.UUID) -> list[LiveVehicle]:
    with sessions() as session:
        return list(live.read_vehicles(session, deployment_id=deployment, after=0, limit=10**9))


def live_score(d: Detections, vehicles: list[LiveVehicle]) -> Metrics:
    """The live vehicles scored as an offline result is: each detection in its vehicle's group,
    every other detection unassigned. `d` names each detection by a unique id."""
    index = {name: i for i, name in enumerate(d.detection_id.tolist())}
    groups = np.full(len(d), -1, dtype=np.int64)
    for k, v in enumerate(vehicles):
        for item in orjson.loads(v.detections_json):
            groups[index[item["detection_id"]]] = k
    metrics = score_grouping(groups, d.target)
    assert metrics is not None
    return metrics
