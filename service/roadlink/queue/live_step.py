"""One step of a deployment's live association, as a worker runs it (issue 18).

A step reads the window of detections not yet settled, [floor - lateness, data clock], runs the
live association's associator over it (`association.pipeline.associate`, the offline one,
unchanged; `assignment` with the model the worker learned at an earlier step,
`association.live_assignment`), decides which vehicles are done (`association.live.settle`),
and publishes them with the next vehicle ids, in one transaction with the detections it
settled and the new state, guarded by the lease. A worker killed at any point before that
commit leaves everything as it was, and the next step (its own, or another worker's once the
lease expired) does the work again: nothing is lost, nothing is published twice, and ids run
on.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import orjson
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association.associators import AssociationError
from roadlink.association.associators.assignment import AssignmentParams
from roadlink.association.detections import Detections, IntArray
from roadlink.association.live import Horizon, done_at, lone_groups, settle
from roadlink.association.live_assignment import Models, associate_window
from roadlink.association.pipeline import associate, parse_params
from roadlink.db.engine import transaction
from roadlink.db.live_records import (
    ClaimedLive,
    NewVehicle,
    StepOutcome,
    claim_live_step,
    commit_step,
    settled_keys,
)
from roadlink.db.models import LiveVehicle
from roadlink.db.repository import KeyedDetections, load_detection_window
from roadlink.logs import log_context
from roadlink.queue.webhooks import record_vehicles_published

log = logging.getLogger(__name__)

FEATURES = ("lane", "length", "vehicle_class")

# The models this worker's `assignment` steps learned, by deployment (live_assignment.py).
MODELS = Models()


def on_vehicles_published(session: Session, vehicles: list[LiveVehicle]) -> None:
    """Called in the transaction that publishes `vehicles` (a step's commit), after they have
    their cursor `seq`: their `vehicle.published` webhook events go to the outbox, so they
    commit with the vehicles, or not at all."""
    record_vehicles_published(session, vehicles)


def run_live_step(
    sessions: sessionmaker[Session],
    *,
    worker_id: str,
    lease_seconds: float,
    published: Callable[[Session, list[LiveVehicle]], None] = on_vehicles_published,
) -> bool:
    """Claim a live association with a step due and run that step; False when none was due."""
    with transaction(sessions) as session:
        claimed = claim_live_step(session, worker_id=worker_id, lease_seconds=lease_seconds)
    if claimed is None:
        return False
    # The step's log lines (the associator's warnings included) name its deployment, as a
    # job's do (roadlink.logs).
    with log_context(deployment_id=claimed.deployment_id):
        started = time.perf_counter()
        with sessions() as session:
            outcome = compute_step(session, claimed, lease_seconds=lease_seconds)
        computed = time.perf_counter()
        with transaction(sessions) as session:
            vehicles = commit_step(session, worker_id=worker_id, step=outcome)
            if vehicles is not None:
                published(session, vehicles)
        log.debug(
            "live step of %s: computed in %.3f s, committed in %.3f s, %d detections open",
            claimed.deployment_id,
            computed - started,
            time.perf_counter() - computed,
            outcome.open_detections,
        )
        if vehicles is None:
            log.info("live step of %s discarded: its lease was lost", claimed.deployment_id)
        elif vehicles:
            log.info(
                "live step of %s published %d vehicles (%s to %s)",
                claimed.deployment_id,
                len(vehicles),
                vehicles[0].vehicle_id,
                vehicles[-1].vehicle_id,
            )
    return True


def compute_step(session: Session, claimed: ClaimedLive, *, lease_seconds: float) -> StepOutcome:
    """What a step publishes and settles, from the database as it stands (nothing written)."""
    clock = claimed.data_clock
    flush = claimed.flush_requested != claimed.flushed
    empty = StepOutcome(claimed, [], [], [], claimed.floor, 0, 0, clock, lease_seconds)
    if clock is None:
        return empty
    start = None if claimed.floor is None else claimed.floor - claimed.lateness
    window = load_detection_window(
        session, deployment_id=claimed.deployment_id, start=start, end=clock
    )
    done = settled_keys(session, deployment_id=claimed.deployment_id, start=start)
    if done:
        keep = np.array(
            [(b, int(r)) not in done for b, r in zip(window.batch_ids, window.rows, strict=True)],
            dtype=bool,
        )
        window = _take(window, np.flatnonzero(keep))
    d = window.detections
    if len(d) == 0:
        return empty
    if d.sensor_positions.size < 2 and not flush:
        # One sensor so far (a gateway per sensor, the first to post): nothing to associate,
        # and no road end to predict passages with; the detections wait for the others.
        return StepOutcome(claimed, [], [], [], claimed.floor, 0, len(d), clock, lease_seconds)
    road_end = max(claimed.road_end or -math.inf, float(d.position.max()))
    horizon = Horizon(
        clock=clock,
        road_end=road_end,
        road_start=float(d.position.min()),
        lateness=claimed.lateness,
        flush=flush,
    )
    if not flush and float(done_at(d, horizon).min()) > clock:
        # No detection of the window is done, so no vehicle is, whatever the associator
        # would say (`settle` publishes a vehicle once its farthest detection is done, and
        # settles a lone one once it is): the step publishes nothing and skips the work.
        floor = min(clock - claimed.lateness, float(d.timestamp.min()))
        return StepOutcome(
            claimed, [], [], [], floor, claimed.open_tracks, len(d), clock, lease_seconds
        )
    groups, confidence = _associate(window, claimed)
    decided = settle(d, groups, horizon, claimed.floor)
    rows = _Rows(window)
    vehicles = [
        _vehicle(rows, members, f"V{claimed.next_vehicle + k}", confidence)
        for k, members in enumerate(decided.publish)
    ]
    return StepOutcome(
        claimed=claimed,
        vehicles=vehicles,
        unassigned=rows.keys(decided.unassigned.tolist()),
        late=rows.keys(decided.late.tolist()),
        floor=decided.floor,
        open_tracks=decided.open_tracks,
        open_detections=decided.open_detections,
        step_clock=clock,
        lease_seconds=lease_seconds,
    )


def _associate(window: KeyedDetections, claimed: ClaimedLive) -> tuple[IntArray, Any]:
    """The associator's groups over the window, and its per-detection link confidences (or
    None). A window it cannot take (one sensor position so far) leaves everything alone."""
    d = window.detections
    if d.sensor_positions.size < 2:
        return lone_groups(len(d)), None
    try:
        if claimed.associator == "assignment":
            return _associate_incrementally(d, claimed)
        result = associate(d, claimed.associator, claimed.params)
    except AssociationError as exc:  # e.g. a supervised associator on unlabelled data
        log.warning("live association of %s: %s", claimed.deployment_id, exc)
        return lone_groups(len(d)), None
    return result.groups, result.link_confidence


def _associate_incrementally(d: Detections, claimed: ClaimedLive) -> tuple[IntArray, Any]:
    """`assignment` with the model this worker learned at an earlier step of the deployment (or
    learning it now), the model kept for the next step (association/live_assignment.py)."""
    params = parse_params(claimed.associator, claimed.params)
    assert isinstance(params, AssignmentParams)
    clock = float(d.timestamp.max()) if claimed.data_clock is None else claimed.data_clock
    # The model is this process's: a worker that restarted or took the lease over learns anew.
    learned = MODELS.get(claimed.deployment_id)
    groups, confidence, learned = associate_window(d.without_labels(), params, clock, learned)
    MODELS.put(claimed.deployment_id, learned)
    return groups, confidence


def _take(window: KeyedDetections, index: IntArray) -> KeyedDetections:
    return KeyedDetections(
        window.detections.take(index),
        window.batch_ids[index],
        window.rows[index],
        window.detection_ids[index],
    )


class _Rows:
    """The window's columns as Python values, converted once a step: a step publishes hundreds
    of vehicles of a few detections each, and reading the columns per vehicle (the features'
    masks over the whole window included) cost more than the associator's own linking pass."""

    def __init__(self, window: KeyedDetections) -> None:
        d = window.detections
        self.detection_id: list[Any] = window.detection_ids.tolist()
        self.batch_id: list[Any] = window.batch_ids.tolist()
        self.row: list[int] = window.rows.tolist()
        self.sensor_id: list[Any] = d.sensor_id.tolist()
        self.position: list[float] = d.position.tolist()
        self.velocity: list[float] = d.velocity.tolist()
        self.timestamp: list[float] = d.timestamp.tolist()
        self.target: list[Any] = d.target.tolist()
        reported = d.features
        self.features = {f: d.feature_values(f) for f in FEATURES if f in reported}

    def keys(self, members: list[int]) -> list[tuple[str, int, float]]:
        return [(str(self.batch_id[i]), self.row[i], self.timestamp[i]) for i in members]

    def item(self, i: int) -> dict[str, Any]:
        """Detection `i` as the feed shows it."""
        item: dict[str, Any] = {
            "detection_id": self.detection_id[i],
            "batch_id": self.batch_id[i],
            "sensor_id": self.sensor_id[i],
            "position": self.position[i],
            "velocity": self.velocity[i],
            "timestamp": self.timestamp[i],
        }
        if self.target[i] is not None:
            item["target"] = self.target[i]
        for f, values in self.features.items():
            if values[i] is not None:
                item[f] = values[i]
        return item


def _vehicle(rows: _Rows, members: IntArray, vehicle_id: str, link_confidence: Any) -> NewVehicle:
    confidence = None
    if link_confidence is not None:
        links = link_confidence[members]
        confidence = float(np.prod(links[np.isfinite(links)]))
    index = members.tolist()
    detections = [rows.item(i) for i in index]
    times = [rows.timestamp[i] for i in index]
    return NewVehicle(
        vehicle_id=vehicle_id,
        confidence=confidence,
        first_timestamp=min(times),
        last_timestamp=max(times),
        detections=detections,
        detections_json=orjson.dumps(detections).decode(),
        keys=rows.keys(index),
    )
