"""Storing a batch, with its job when association is asked for, in one transaction
(`roadlink.services.batches`)."""

from __future__ import annotations

import uuid

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session

from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import make_session_factory
from roadlink.db.json_columns import BatchSelection
from roadlink.db.models import Batch, Deployment
from roadlink.services.batches import ParsedBatch, batch_job, store_batch, store_batch_once
from roadlink.services.idempotency import IdempotentRequest
from roadlink.services.problems import ServiceProblem
from roadlink.settings import Settings
from tests.helpers import row_counts
from tests.services.asked import Associate


def _deployment(engine: Engine) -> uuid.UUID:
    with make_session_factory(engine).begin() as session:
        return repository.create_deployment(session, name="road", sensors=None).id


def test_a_batch_asking_for_association_is_stored_with_its_job(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    deployment_id = _deployment(engine)
    with make_session_factory(engine).begin() as session:
        parsed = ParsedBatch(paper_batch, "json", Associate("kmeans", {"n_targets": 10}))
        batch = store_batch(session, settings=settings, deployment_id=deployment_id, batch=parsed)
        job = batch_job(session, batch)
    assert job is not None and job.selection == BatchSelection((batch.id,))
    assert (job.associator, job.params["n_targets"], job.max_attempts) == (
        "kmeans",
        10,
        settings.max_attempts,
    )
    assert batch.n_detections == len(paper_batch) and batch.source == "json"


def test_the_answer_shows_the_enqueued_job_without_reading_it_back(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    """The session holds a flushed row weakly: the job a batch enqueued is kept with the batch, so
    the POST's answer reads nothing more before its commit."""
    from sqlalchemy import event

    deployment_id = _deployment(engine)
    statements: list[str] = []

    def record(*args: object) -> None:
        statements.append(str(args[2]))

    with make_session_factory(engine).begin() as session:
        parsed = ParsedBatch(paper_batch, "json", Associate("kmeans", {"n_targets": 10}))
        batch = store_batch(session, settings=settings, deployment_id=deployment_id, batch=parsed)
        event.listen(engine, "before_cursor_execute", record)
        try:
            job = batch_job(session, batch)
            assert job is not None and job.id == batch.job_id
            assert (job.state, job.lease_owner, job.finished_at) == ("queued", None, None)
        finally:
            event.remove(engine, "before_cursor_execute", record)
    assert statements == []


def test_a_batch_without_association_has_no_job(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    deployment_id = _deployment(engine)
    with make_session_factory(engine).begin() as session:
        parsed = ParsedBatch(paper_batch, "csv", None)
        batch = store_batch(session, settings=settings, deployment_id=deployment_id, batch=parsed)
        assert batch_job(session, batch) is None


def test_bad_parameters_store_nothing(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    deployment_id = _deployment(engine)
    before = row_counts(engine)
    with pytest.raises(ServiceProblem) as raised, Session(engine) as session:
        parsed = ParsedBatch(paper_batch, "json", Associate("kmeans", {"n_targets": "many"}))
        store_batch_once(
            session,
            settings=settings,
            deployment_id=deployment_id,
            parse=lambda _deployment: parsed,
            answer=lambda batch: batch.id,
            idempotent=None,
        )
    assert raised.value.status == 422 and raised.value.errors[0].field == "associate.params"
    assert row_counts(engine) == before


def test_a_batch_is_parsed_against_its_deployment_and_stored_once_per_key(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    deployment_id = _deployment(engine)
    parsed_for: list[uuid.UUID] = []

    def parse(deployment: Deployment) -> ParsedBatch:
        parsed_for.append(deployment.id)
        return ParsedBatch(paper_batch, "csv", None)

    def store() -> tuple[uuid.UUID, bool]:
        with Session(engine) as session:
            return store_batch_once(
                session,
                settings=settings,
                deployment_id=deployment_id,
                parse=parse,
                answer=lambda batch: batch.id,
                idempotent=IdempotentRequest(key="k", principal="p", digest="d"),
            )

    first, replayed_first = store()
    again, replayed_again = store()
    assert (replayed_first, replayed_again) == (False, True)
    assert first == again and parsed_for == [deployment_id]
    with Session(engine) as session:
        stored = session.get(Batch, first)
        assert stored is not None
        assert (stored.idempotency_key, stored.idempotency_principal) == ("k", "p")


def test_a_batch_for_a_missing_deployment_is_a_404(
    engine: Engine, settings: Settings, paper_batch: Detections
) -> None:
    with pytest.raises(ServiceProblem) as raised, Session(engine) as session:
        store_batch_once(
            session,
            settings=settings,
            deployment_id=uuid.uuid4(),
            parse=lambda _deployment: ParsedBatch(paper_batch, "csv", None),
            answer=lambda batch: batch.id,
            idempotent=None,
        )
    assert raised.value.status == 404
