"""News of the queue is sent by the transaction that makes it true: delivered at its commit,
never when it rolls back. PostgreSQL: NOTIFY; SQLite: in-process signals after the commit."""

from __future__ import annotations

import uuid
from collections.abc import Iterator
from typing import Any

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association import associate
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import transaction
from roadlink.db.json_columns import BatchSelection
from roadlink.queue import claim_next_job, complete_job, enqueue_job
from roadlink.queue.transitions import (
    FINISHED_CHANNEL,
    NOTIFY_CHANNEL,
    local_enqueue_signal,
    subscribe_local_finishes,
    unsubscribe_local_finishes,
)
from roadlink.queue.wakeup import libpq_conninfo


class Rollback(Exception):
    """Raised to roll a transaction back."""


def _store_batch(sessions: sessionmaker[Session], detections: Detections) -> tuple[Any, Any]:
    with transaction(sessions) as session:
        deployment = repository.create_deployment(session, name="road", sensors=None)
        batch = repository.insert_batch(
            session, deployment_id=deployment.id, detections=detections, source="simulation"
        )
    return deployment.id, batch.id


def _enqueue(
    sessions: sessionmaker[Session], deployment_id: Any, batch_id: Any, *, commit: bool
) -> uuid.UUID:
    job_id = uuid.uuid4()
    try:
        with transaction(sessions) as session:
            enqueue_job(
                session,
                deployment_id=deployment_id,
                selection=BatchSelection((batch_id,)),
                associator="kmeans++",
                params={},
                max_attempts=1,
                job_id=job_id,
            )
            if not commit:
                raise Rollback
    except Rollback:
        pass
    return job_id


def _finish(
    sessions: sessionmaker[Session], detections: Detections, *, commit: bool
) -> uuid.UUID | None:
    """Claim the oldest job and complete it, committing or not; the id of the job."""
    with transaction(sessions) as session:
        job = claim_next_job(session, worker_id="w", lease_seconds=30)
    assert job is not None
    try:
        with transaction(sessions) as session:
            assert complete_job(
                session,
                job_id=job.id,
                worker_id="w",
                result=associate(detections),
                duration_seconds=0.1,
            )
            if not commit:
                raise Rollback
    except Rollback:
        return None
    return job.id


@pytest.fixture
def listener(engine: Engine, database_url: str) -> Iterator[Any]:
    """A PostgreSQL connection listening on both queue channels."""
    if engine.dialect.name != "postgresql":
        pytest.skip("NOTIFY is PostgreSQL's; SQLite is covered by the in-process test")
    import psycopg

    with psycopg.connect(libpq_conninfo(database_url), autocommit=True) as connection:
        connection.execute(f"LISTEN {NOTIFY_CHANNEL}")
        connection.execute(f"LISTEN {FINISHED_CHANNEL}")
        yield connection


def _received(connection: Any) -> list[tuple[str, str]]:
    return [(n.channel, n.payload) for n in connection.notifies(timeout=0.5)]


def test_postgres_notifies_at_commit_only(
    sessions: sessionmaker[Session], paper_batch: Detections, listener: Any
) -> None:
    deployment_id, batch_id = _store_batch(sessions, paper_batch)
    _enqueue(sessions, deployment_id, batch_id, commit=False)
    assert _received(listener) == []
    job_id = _enqueue(sessions, deployment_id, batch_id, commit=True)
    assert _received(listener) == [(NOTIFY_CHANNEL, str(job_id))]

    assert _finish(sessions, paper_batch, commit=False) is None
    assert _received(listener) == []
    # The rolled-back finish left the job running as "w"'s; a new one is claimed and finished.
    job_id = _enqueue(sessions, deployment_id, batch_id, commit=True)
    assert _received(listener) == [(NOTIFY_CHANNEL, str(job_id))]
    finished = _finish(sessions, paper_batch, commit=True)
    assert _received(listener) == [(FINISHED_CHANNEL, str(finished))]


def test_sqlite_signals_this_process_after_commit_only(
    engine: Engine, sessions: sessionmaker[Session], paper_batch: Detections
) -> None:
    if engine.dialect.name != "sqlite":
        pytest.skip("in-process signals are SQLite's; PostgreSQL notifies")
    finished: list[str] = []
    subscribe_local_finishes(finished.extend)
    try:
        deployment_id, batch_id = _store_batch(sessions, paper_batch)
        local_enqueue_signal.clear()
        _enqueue(sessions, deployment_id, batch_id, commit=False)
        assert not local_enqueue_signal.is_set()
        _enqueue(sessions, deployment_id, batch_id, commit=True)
        assert local_enqueue_signal.is_set()

        assert _finish(sessions, paper_batch, commit=False) is None
        assert finished == []
        _enqueue(sessions, deployment_id, batch_id, commit=True)
        job_id = _finish(sessions, paper_batch, commit=True)
        assert finished == [str(job_id)]
    finally:
        unsubscribe_local_finishes(finished.extend)
        local_enqueue_signal.clear()
