"""The live association's rows (issue 18): its state per deployment, its lease, the vehicles it
published and the detections it settled. Keyword-only data functions that never commit."""

from __future__ import annotations

import uuid
from collections.abc import Sequence
from dataclasses import dataclass
from datetime import timedelta
from typing import Any, cast

import numpy as np
import numpy.typing as npt
import orjson
from sqlalchemy import Table, bindparam, case, func, insert, or_, select, update
from sqlalchemy.orm import Session

from roadlink.db.drivers import Driver, driver_of, prebuilt
from roadlink.db.models import LiveAssociation, LiveSettledDetection, LiveVehicle

LIVE_CHANNEL = "roadlink_jobs"
"""Workers hear of new live data on the queue's own channel: an idle worker listens there
already, and a live step is work like a job (`roadlink.queue.transitions.NOTIFY_CHANNEL`)."""


def get_live(session: Session, *, deployment_id: uuid.UUID) -> LiveAssociation | None:
    """The deployment's live association (active or stopped), or None."""
    return session.get(LiveAssociation, deployment_id)


def start_live(
    session: Session,
    *,
    deployment_id: uuid.UUID,
    associator: str,
    params: dict[str, Any],
    lateness: float,
    data_clock: float | None,
    road_end: float | None,
) -> LiveAssociation:
    """Start (or change, or restart) the deployment's live association. A restart keeps its
    vehicle numbering and what it settled; its clock starts from the data already stored."""
    live = get_live(session, deployment_id=deployment_id)
    if live is None:
        live = LiveAssociation(
            deployment_id=deployment_id,
            received=0,
            processed=0,
            flush_requested=0,
            flushed=0,
            open_tracks=0,
            open_detections=0,
            next_vehicle=1,
            vehicles_published=0,
            late_detections=0,
        )
        session.add(live)
    live.associator, live.params, live.lateness, live.active = associator, params, lateness, True
    live.data_clock = _newest(live.data_clock, data_clock)
    live.road_end = _newest(live.road_end, road_end)
    live.received = (live.received or 0) + 1  # a step is due: the data stored so far
    session.flush()
    driver_of(session).notify(session, LIVE_CHANNEL, [""])
    return live


def _newest(a: float | None, b: float | None) -> float | None:
    return b if a is None else a if b is None else max(a, b)


def note_batch(
    session: Session,
    *,
    deployment_id: uuid.UUID,
    timestamps: npt.NDArray[np.float64],
    last_position: float,
) -> bool:
    """A batch of the deployment was stored in this transaction: advance its live data clock
    and make a step due, waking the workers at commit. Its detections older than the window
    the next step reads (`floor - lateness`) are counted late now, since no step will see them
    (offline jobs still do). False when no live association runs."""

    # Built once: every batch asks, and most deployments run no live association.
    statement, _ = prebuilt(session, "note-batch", _build_note_batch)
    row = (
        session.connection()
        .execute(
            statement,
            {
                "deployment": deployment_id,
                "newest_timestamp": float(timestamps.max()),
                "last_position": float(last_position),
            },
        )
        .first()
    )
    if row is None:
        return False
    floor, lateness = row
    if floor is not None:
        late = int(np.count_nonzero(timestamps < floor - lateness))
        if late:
            session.execute(
                update(LiveAssociation)
                .where(LiveAssociation.deployment_id == deployment_id)
                .values(late_detections=LiveAssociation.late_detections + late)
                .execution_options(synchronize_session=False)
            )
    driver_of(session).notify(session, LIVE_CHANNEL, [""])
    return True


def request_flush(session: Session, *, deployment_id: uuid.UUID) -> bool:
    """Ask for every open track to be finished at the next step; False when not running."""
    statement = (
        update(LiveAssociation)
        .where(LiveAssociation.deployment_id == deployment_id, LiveAssociation.active.is_(True))
        .values(flush_requested=LiveAssociation.flush_requested + 1)
        .execution_options(synchronize_session=False)
    )
    if session.execute(statement).rowcount != 1:  # type: ignore[attr-defined]
        return False
    driver_of(session).notify(session, LIVE_CHANNEL, [""])
    return True


def stop_live(session: Session, *, deployment_id: uuid.UUID) -> bool:
    """Stop it (its vehicles stay, and its row, for a restart); False when it was not running."""
    statement = (
        update(LiveAssociation)
        .where(LiveAssociation.deployment_id == deployment_id, LiveAssociation.active.is_(True))
        .values(active=False, lease_owner=None, lease_expires_at=None)
        .execution_options(synchronize_session=False)
    )
    return session.execute(statement).rowcount == 1  # type: ignore[attr-defined]


def _due() -> Any:
    return LiveAssociation.active.is_(True) & (
        (LiveAssociation.received != LiveAssociation.processed)
        | (LiveAssociation.flush_requested != LiveAssociation.flushed)
    )


def _free_for(worker_id: Any, now: Any) -> Any:
    return or_(
        LiveAssociation.lease_owner.is_(None),
        LiveAssociation.lease_owner == worker_id,
        LiveAssociation.lease_expires_at < now,
    )


def _build_note_batch(driver: Driver, now: Any, bound: bool) -> Any:
    table = cast(Table, LiveAssociation.__table__)
    live = table.c

    def at_least(column: Any, name: str) -> Any:
        value = bindparam(name, type_=column.type)
        return case((or_(column.is_(None), column < value), value), else_=column)

    return (
        update(table)
        .where(live.deployment_id == bindparam("deployment"), live.active.is_(True))
        .values(
            data_clock=at_least(live.data_clock, "newest_timestamp"),
            road_end=at_least(live.road_end, "last_position"),
            received=live.received + 1,
        )
        .returning(live.floor, live.lateness)
    )


def has_live_step(session: Session, *, worker_id: str) -> bool:
    """Whether a live association has a step due that this worker may take (a read; built once,
    as an idle worker asks it at every wake-up)."""
    query, params = prebuilt(session, "live-due", _build_live_due)
    return (
        session.connection().execute(query, params | {"worker_id": worker_id}).first() is not None
    )


def _build_live_due(driver: Driver, now: Any, bound: bool) -> Any:
    free = _free_for(bindparam("worker_id", type_=LiveAssociation.lease_owner.type), now)
    return select(LiveAssociation.deployment_id).where(_due(), free).limit(1)


@dataclass(frozen=True)
class ClaimedLive:
    """A live association a worker holds the lease of, as it stood when claimed."""

    deployment_id: uuid.UUID
    associator: str
    params: dict[str, Any]
    lateness: float
    data_clock: float | None
    road_end: float | None
    received: int
    flush_requested: int
    flushed: int
    floor: float | None
    next_vehicle: int
    open_tracks: int


def claim_live_step(
    session: Session, *, worker_id: str, lease_seconds: float
) -> ClaimedLive | None:
    """Take the lease of a live association with a step due: one this worker holds, one nobody
    holds, or one whose holder's lease expired (it died); the least recently stepped first.
    One statement, locked as a job claim is (`Driver.lock_for_claim`)."""
    now = driver_of(session).clock()
    candidate = driver_of(session).lock_for_claim(
        select(LiveAssociation.deployment_id)
        .where(_due(), _free_for(worker_id, now))
        .order_by(LiveAssociation.last_step_at.is_not(None), LiveAssociation.last_step_at)
        .limit(1)
    )
    statement = (
        update(LiveAssociation)
        .where(LiveAssociation.deployment_id == candidate.scalar_subquery(), _due())
        .values(lease_owner=worker_id, lease_expires_at=now + timedelta(seconds=lease_seconds))
        .returning(
            LiveAssociation.deployment_id,
            LiveAssociation.associator,
            LiveAssociation.params,
            LiveAssociation.lateness,
            LiveAssociation.data_clock,
            LiveAssociation.road_end,
            LiveAssociation.received,
            LiveAssociation.flush_requested,
            LiveAssociation.flushed,
            LiveAssociation.floor,
            LiveAssociation.next_vehicle,
            LiveAssociation.open_tracks,
        )
        .execution_options(synchronize_session=False)
    )
    row = session.execute(statement).first()
    return None if row is None else ClaimedLive(*row)


def release_live_leases(session: Session, *, worker_id: str) -> int:
    """Give up every lease this worker holds (it is stopping)."""
    statement = (
        update(LiveAssociation)
        .where(LiveAssociation.lease_owner == worker_id)
        .values(lease_owner=None, lease_expires_at=None)
        .execution_options(synchronize_session=False)
    )
    return int(session.execute(statement).rowcount)  # type: ignore[attr-defined]


def settled_keys(
    session: Session, *, deployment_id: uuid.UUID, start: float | None
) -> set[tuple[str, int]]:
    """(batch id, row) of the deployment's settled detections from `start` on."""
    query = select(LiveSettledDetection.batch_id, LiveSettledDetection.row).where(
        LiveSettledDetection.deployment_id == deployment_id
    )
    if start is not None:
        query = query.where(LiveSettledDetection.timestamp >= start)
    return {(str(b), int(r)) for b, r in session.execute(query).all()}


@dataclass(frozen=True)
class NewVehicle:
    """A vehicle to publish, and the keys of its detections."""

    vehicle_id: str
    confidence: float | None
    first_timestamp: float
    last_timestamp: float
    detections: list[dict[str, Any]]
    detections_json: str
    keys: list[tuple[str, int, float]]  # (batch id, row, timestamp)


@dataclass(frozen=True)
class StepOutcome:
    """What a step changes in its live association's row."""

    claimed: ClaimedLive
    vehicles: list[NewVehicle]
    unassigned: list[tuple[str, int, float]]
    late: list[tuple[str, int, float]]
    floor: float | None
    open_tracks: int
    open_detections: int
    step_clock: float | None
    lease_seconds: float


def commit_step(session: Session, *, worker_id: str, step: StepOutcome) -> list[LiveVehicle] | None:
    """Record a step: its vehicles, the detections it settled and the new state, all in the
    caller's transaction, guarded by the lease: None (and nothing written) when this worker no
    longer holds it. The lease is renewed, so the same worker takes the next step."""
    claimed = step.claimed
    now = driver_of(session).clock()
    guard = update(LiveAssociation).where(
        LiveAssociation.deployment_id == claimed.deployment_id,
        LiveAssociation.lease_owner == worker_id,
        LiveAssociation.active.is_(True),
    )
    values: dict[str, Any] = {
        "processed": claimed.received,
        "flushed": claimed.flush_requested,
        "floor": step.floor,
        "open_tracks": step.open_tracks,
        "open_detections": step.open_detections,
        "step_clock": step.step_clock,
        "next_vehicle": claimed.next_vehicle + len(step.vehicles),
        "vehicles_published": LiveAssociation.vehicles_published + len(step.vehicles),
        "late_detections": LiveAssociation.late_detections + len(step.late),
        "lease_expires_at": now + timedelta(seconds=step.lease_seconds),
        "last_step_at": now,
    }
    # The guard also checks that no other step ran since the claim (next_vehicle unchanged).
    statement = guard.where(LiveAssociation.next_vehicle == claimed.next_vehicle).values(**values)
    if session.execute(statement.execution_options(synchronize_session=False)).rowcount != 1:  # type: ignore[attr-defined]
        return None
    published = [
        LiveVehicle(
            deployment_id=claimed.deployment_id,
            vehicle_id=v.vehicle_id,
            revision=1,
            final=True,
            confidence=v.confidence,
            first_timestamp=v.first_timestamp,
            last_timestamp=v.last_timestamp,
            n_detections=len(v.keys),
            detections_json=v.detections_json,
            published_at=now,
        )
        for v in step.vehicles
    ]
    session.add_all(published)
    session.flush()
    settled = [
        {"batch_id": uuid.UUID(b), "row": r, "timestamp": t, "vehicle_seq": p.seq, "late": False}
        for p, v in zip(published, step.vehicles, strict=True)
        for b, r, t in v.keys
    ]
    settled += [
        {"batch_id": uuid.UUID(b), "row": r, "timestamp": t, "vehicle_seq": None, "late": late}
        for keys, late in ((step.unassigned, False), (step.late, True))
        for b, r, t in keys
    ]
    if settled:
        for item in settled:
            item["deployment_id"] = claimed.deployment_id
        session.execute(insert(LiveSettledDetection), settled)
    return published


def list_vehicles(
    session: Session, *, deployment_id: uuid.UUID, after: int, limit: int
) -> Sequence[LiveVehicle]:
    """The deployment's published vehicles after the cursor `after`, in publication order."""
    query = (
        select(LiveVehicle)
        .where(LiveVehicle.deployment_id == deployment_id, LiveVehicle.seq > after)
        .order_by(LiveVehicle.seq)
        .limit(limit)
    )
    return session.scalars(query).all()


def recent_vehicles(session: Session, *, deployment_id: uuid.UUID, limit: int) -> list[LiveVehicle]:
    """The deployment's last `limit` published vehicles, oldest first."""
    query = (
        select(LiveVehicle)
        .where(LiveVehicle.deployment_id == deployment_id)
        .order_by(LiveVehicle.seq.desc())
        .limit(limit)
    )
    return list(reversed(session.scalars(query).all()))


def count_settled(session: Session, *, deployment_id: uuid.UUID) -> int:
    """How many of the deployment's detections the live association has settled."""
    query = select(func.count()).where(LiveSettledDetection.deployment_id == deployment_id)
    return int(session.scalar(query) or 0)


def vehicle_document(vehicle: LiveVehicle) -> dict[str, Any]:
    """A published vehicle as the feed (and its `vehicle.published` webhook event) shows it."""
    return {
        "vehicle_id": vehicle.vehicle_id,
        "revision": vehicle.revision,
        "final": vehicle.final,
        "confidence": vehicle.confidence,
        "first_timestamp": vehicle.first_timestamp,
        "last_timestamp": vehicle.last_timestamp,
        "cursor": str(vehicle.seq),
        "detections": orjson.loads(vehicle.detections_json),
    }
