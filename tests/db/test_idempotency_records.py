"""Where each endpoint keeps its Idempotency-Keys: per sender (and deployment, for batches),
and forgotten once old (`roadlink.db.idempotency_records`)."""

from __future__ import annotations

from datetime import timedelta

import pytest
from sqlalchemy import Engine
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session

from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.idempotency_records import (
    find_batch_idempotency_key,
    find_job_idempotency_key,
    forget_idempotency_keys,
    record_job_idempotency_key,
)
from roadlink.db.json_columns import BatchSelection
from roadlink.db.models import Batch, utcnow
from roadlink.queue import enqueue_job


def _keyed_batch(session: Session, detections: Detections, principal: str, key: str) -> Batch:
    deployment = repository.create_deployment(session, name="road", sensors=None)
    return repository.insert_batch(
        session,
        deployment_id=deployment.id,
        detections=detections,
        source="csv",
        idempotency_key=key,
        idempotency_principal=principal,
        request_sha256="0" * 64,
    )


def test_a_batch_key_is_found_by_its_sender_only(engine: Engine, paper_batch: Detections) -> None:
    with Session(engine) as session, session.begin():
        batch = _keyed_batch(session, paper_batch, "alice", "k")
        find = find_batch_idempotency_key
        assert (
            find(session, deployment_id=batch.deployment_id, principal="alice", idempotency_key="k")
            is batch
        )
        assert (
            find(session, deployment_id=batch.deployment_id, principal="bob", idempotency_key="k")
            is None
        )


def test_a_sender_uses_a_batch_key_once_per_deployment(
    engine: Engine, paper_batch: Detections
) -> None:
    with Session(engine) as session, session.begin():
        batch = _keyed_batch(session, paper_batch, "alice", "k")
        with pytest.raises(IntegrityError):
            repository.insert_batch(
                session,
                deployment_id=batch.deployment_id,
                detections=paper_batch,
                source="csv",
                idempotency_key="k",
                idempotency_principal="alice",
                request_sha256="1" * 64,
            )


def test_old_keys_are_forgotten_and_what_they_created_stays(
    engine: Engine, paper_batch: Detections
) -> None:
    with Session(engine) as session, session.begin():
        batch = _keyed_batch(session, paper_batch, "alice", "k")
        job = enqueue_job(
            session,
            deployment_id=batch.deployment_id,
            selection=BatchSelection((batch.id,)),
            associator="kmeans",
            params={},
            max_attempts=1,
        )
        record_job_idempotency_key(
            session, principal="alice", idempotency_key="j", request_sha256="2" * 64, job_id=job.id
        )
        assert find_job_idempotency_key(session, principal="alice", idempotency_key="j")
        assert find_job_idempotency_key(session, principal="bob", idempotency_key="j") is None
        kept = forget_idempotency_keys(session, created_before=utcnow() - timedelta(hours=1))
        assert (kept.batches, kept.jobs) == (0, 0)
        forgotten = forget_idempotency_keys(session, created_before=utcnow() + timedelta(hours=1))
        assert (forgotten.batches, forgotten.jobs) == (1, 1)
        session.refresh(batch)
        assert (batch.idempotency_key, batch.idempotency_principal, batch.request_sha256) == (
            None,
            None,
            None,
        )
        assert find_job_idempotency_key(session, principal="alice", idempotency_key="j") is None
        assert repository.get_job(session, job_id=job.id) is not None
