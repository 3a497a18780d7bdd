"""A live association's rows (`roadlink.db.live_records`), on both databases: a batch makes a
step due and moves the clock, one worker at a time holds a deployment's lease, a step commits
whole or, once its lease is lost, not at all, and the feed reads back in publication order."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime, timedelta

import numpy as np
import pytest
from sqlalchemy import Engine, update
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db import live_records, repository
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import LiveAssociation
from roadlink.simulation import preset, simulate

LEASE = 30.0


@pytest.fixture
def sessions(engine: Engine) -> sessionmaker[Session]:
    return make_session_factory(engine)


@pytest.fixture
def running(sessions: sessionmaker[Session]) -> uuid.UUID:
    """A deployment whose live association was just started (a step due: the data so far)."""
    with transaction(sessions) as session:
        deployment = repository.create_deployment(session, name="live", sensors=None).id
        live_records.start_live(
            session,
            deployment_id=deployment,
            associator="assignment",
            params={},
            lateness=5.0,
            data_clock=None,
            road_end=None,
        )
    return deployment


def _claim(sessions: sessionmaker[Session], worker: str) -> live_records.ClaimedLive | None:
    with transaction(sessions) as session:
        return live_records.claim_live_step(session, worker_id=worker, lease_seconds=LEASE)


def _state(sessions: sessionmaker[Session], deployment: uuid.UUID) -> LiveAssociation:
    with sessions() as session:
        live = live_records.get_live(session, deployment_id=deployment)
        assert live is not None
        return live


def _empty_step(claimed: live_records.ClaimedLive, **changes: object) -> live_records.StepOutcome:
    fields: dict[str, object] = {
        "claimed": claimed,
        "vehicles": [],
        "unassigned": [],
        "late": [],
        "floor": claimed.floor,
        "open_tracks": 0,
        "open_detections": 0,
        "step_clock": claimed.data_clock,
        "lease_seconds": LEASE,
    }
    return live_records.StepOutcome(**{**fields, **changes})  # type: ignore[arg-type]


def test_a_batch_moves_the_clock_forward_only_and_makes_a_step_due(
    sessions: sessionmaker[Session], running: uuid.UUID
) -> None:
    claimed = _claim(sessions, "w1")
    assert claimed is not None and claimed.data_clock is None
    with transaction(sessions) as session:
        live_records.commit_step(session, worker_id="w1", step=_empty_step(claimed))
        assert not live_records.has_live_step(session, worker_id="w1")
    for times, position in (([10.0, 30.0], 100.0), ([20.0], 50.0)):
        with transaction(sessions) as session:
            assert live_records.note_batch(
                session,
                deployment_id=running,
                timestamps=np.array(times),
                last_position=position,
            )
    state = _state(sessions, running)
    assert (state.data_clock, state.road_end) == (30.0, 100.0)  # never back
    with sessions() as session:
        # Due again, for w1: a step renews its lease, so the same worker takes the next.
        assert live_records.has_live_step(session, worker_id="w1")
        assert not live_records.has_live_step(session, worker_id="w2")


def test_a_batch_of_a_deployment_without_a_running_association_changes_nothing(
    sessions: sessionmaker[Session], running: uuid.UUID
) -> None:
    with transaction(sessions) as session:
        assert live_records.stop_live(session, deployment_id=running)
        assert not live_records.stop_live(session, deployment_id=running)  # stopped already
        assert not live_records.request_flush(session, deployment_id=running)
        assert not live_records.note_batch(
            session, deployment_id=running, timestamps=np.array([1.0]), last_position=0.0
        )
    assert _state(sessions, running).data_clock is None
    assert _claim(sessions, "w1") is None  # a stopped association has no step


def test_one_worker_holds_the_lease_until_it_expires_or_is_given_back(
    sessions: sessionmaker[Session], running: uuid.UUID
) -> None:
    assert _claim(sessions, "w1") is not None
    assert _claim(sessions, "w2") is None
    with sessions() as session:
        assert not live_records.has_live_step(session, worker_id="w2")
        assert live_records.has_live_step(session, worker_id="w1")  # its own, still due
    with transaction(sessions) as session:
        assert live_records.release_live_leases(session, worker_id="w1") == 1
    assert _claim(sessions, "w2") is not None
    with transaction(sessions) as session:  # w2 dies: its lease runs out
        session.execute(
            update(LiveAssociation)
            .where(LiveAssociation.deployment_id == running)
            .values(lease_expires_at=datetime.now(UTC) - timedelta(seconds=1))
        )
    assert _claim(sessions, "w3") is not None


def test_a_step_commits_whole_and_a_lost_lease_writes_nothing(
    sessions: sessionmaker[Session], running: uuid.UUID
) -> None:
    d = simulate(preset("small"), seed=1).detections
    with transaction(sessions) as session:
        batch = repository.insert_batch(
            session, deployment_id=running, detections=d, source="simulation"
        )
    claimed = _claim(sessions, "w1")
    assert claimed is not None
    keys = [(str(batch.id), row, float(d.timestamp[row])) for row in range(3)]
    vehicle = live_records.NewVehicle(
        vehicle_id="V1",
        confidence=0.9,
        first_timestamp=keys[0][2],
        last_timestamp=keys[1][2],
        detections=[],
        detections_json="[]",
        keys=keys[:2],
    )
    step = _empty_step(claimed, vehicles=[vehicle], late=keys[2:], floor=5.0)
    with transaction(sessions) as session:  # another worker took over meanwhile
        session.execute(
            update(LiveAssociation)
            .where(LiveAssociation.deployment_id == running)
            .values(lease_owner="w2")
        )
    with transaction(sessions) as session:
        assert live_records.commit_step(session, worker_id="w1", step=step) is None
        assert live_records.count_settled(session, deployment_id=running) == 0
        session.execute(
            update(LiveAssociation)
            .where(LiveAssociation.deployment_id == running)
            .values(lease_owner="w1")
        )
    with transaction(sessions) as session:
        published = live_records.commit_step(session, worker_id="w1", step=step)
        assert published is not None and [v.vehicle_id for v in published] == ["V1"]
    # Once committed, the same claim's step is refused: another step ran since.
    with transaction(sessions) as session:
        assert live_records.commit_step(session, worker_id="w1", step=step) is None
    state = _state(sessions, running)
    assert (state.next_vehicle, state.vehicles_published, state.late_detections) == (2, 1, 1)
    assert state.floor == 5.0 and state.processed == claimed.received
    with sessions() as session:
        assert live_records.count_settled(session, deployment_id=running) == 3
        assert live_records.settled_keys(session, deployment_id=running, start=None) == {
            (b, r) for b, r, _ in keys
        }
        later = live_records.settled_keys(session, deployment_id=running, start=keys[1][2])
        assert later == {(b, r) for b, r, t in keys if t >= keys[1][2]}


def test_a_batch_older_than_the_window_is_counted_late(
    sessions: sessionmaker[Session], running: uuid.UUID
) -> None:
    claimed = _claim(sessions, "w1")
    assert claimed is not None
    with transaction(sessions) as session:
        live_records.commit_step(session, worker_id="w1", step=_empty_step(claimed, floor=100.0))
    with transaction(sessions) as session:
        # The next step reads from floor - lateness = 95 s: two of these are behind it.
        live_records.note_batch(
            session,
            deployment_id=running,
            timestamps=np.array([90.0, 94.0, 96.0]),
            last_position=0.0,
        )
    assert _state(sessions, running).late_detections == 2
