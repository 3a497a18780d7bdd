"""Creating a job: its parameters checked, its selection resolved to one deployment holding
detections of two sensor positions at least, enqueued once per Idempotency-Key
(`roadlink.services.jobs`)."""

from __future__ import annotations

import uuid
from collections.abc import Callable

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import make_session_factory
from roadlink.db.json_columns import BatchSelection, WindowSelection
from roadlink.services.idempotency import IdempotentRequest
from roadlink.services.jobs import (
    checked_params,
    create_job_once,
    require_job,
    resolve_selection,
)
from roadlink.services.problems import ServiceProblem
from roadlink.settings import Settings
from tests.helpers import row_counts
from tests.services.asked import Associate, Job

Store = Callable[..., uuid.UUID]


@pytest.fixture
def sessions(engine: Engine) -> sessionmaker[Session]:
    return make_session_factory(engine)


@pytest.fixture
def store(sessions: sessionmaker[Session]) -> Store:
    """Store detections as a batch of a deployment (a new one unless given); the batch's id."""

    def store_batch(detections: Detections, deployment_id: uuid.UUID | None = None) -> uuid.UUID:
        with sessions.begin() as session:
            if deployment_id is None:
                deployment_id = repository.create_deployment(session, name="r", sensors=None).id
            batch = repository.insert_batch(
                session, deployment_id=deployment_id, detections=detections, source="csv"
            )
            return batch.id

    return store_batch


def _deployment_of(sessions: sessionmaker[Session], batch_id: uuid.UUID) -> uuid.UUID:
    with sessions() as session:
        batch = repository.get_batch(session, batch_id=batch_id)
        assert batch is not None
        return batch.deployment_id


def _problem(sessions: sessionmaker[Session], asked: Job) -> ServiceProblem:
    with pytest.raises(ServiceProblem) as raised, sessions() as session:
        resolve_selection(session, asked)
    return raised.value


@pytest.mark.parametrize(
    ("asked", "field"),
    [
        (Associate("no-such-associator"), "associate.associator"),
        (Associate("kmeans", {"n_targets": "many"}), "associate.params"),
    ],
)
def test_parameters_are_checked_before_anything_is_queued(asked: Associate, field: str) -> None:
    with pytest.raises(ServiceProblem) as raised:
        checked_params(asked)
    assert raised.value.status == 422 and raised.value.errors[0].field == field


def test_defaults_are_filled_in() -> None:
    assert checked_params(Associate("kmeans"))["max_iter"] == 300


def test_batches_of_one_deployment_are_selected_once_each(
    sessions: sessionmaker[Session], store: Store, paper_batch: Detections
) -> None:
    first = store(paper_batch)
    deployment_id = _deployment_of(sessions, first)
    second = store(paper_batch, deployment_id)
    with sessions() as session:
        resolved = resolve_selection(session, Job(batch_ids=[second, first, second]))
    assert resolved == (deployment_id, BatchSelection((second, first)))


def test_a_window_is_selected_on_its_deployment(
    sessions: sessionmaker[Session], store: Store, paper_batch: Detections
) -> None:
    deployment_id = _deployment_of(sessions, store(paper_batch))
    with sessions() as session:
        resolved = resolve_selection(session, Job(deployment_id=deployment_id, start=0.0))
    assert resolved == (deployment_id, WindowSelection(0.0, None))


def test_what_cannot_be_selected_is_named(
    sessions: sessionmaker[Session], store: Store, paper_batch: Detections
) -> None:
    missing = uuid.uuid4()
    assert _problem(sessions, Job(deployment_id=missing)).status == 404
    problem = _problem(sessions, Job(batch_ids=[store(paper_batch), missing]))
    assert problem.status == 422 and problem.errors[0].field == "batch_ids.1"
    problem = _problem(sessions, Job(batch_ids=[store(paper_batch), store(paper_batch)]))
    assert "different deployments" in problem.detail


def test_a_selection_without_two_sensor_positions_is_refused(
    sessions: sessionmaker[Session], store: Store, paper_batch: Detections
) -> None:
    deployment_id = _deployment_of(sessions, store(paper_batch))
    assert "no detections" in _problem(sessions, Job(deployment_id=deployment_id, start=1e9)).detail
    one_sensor = paper_batch.take(paper_batch.position == paper_batch.position[0])
    problem = _problem(sessions, Job(batch_id=store(one_sensor)))
    assert problem.status == 422 and "one sensor position" in problem.detail


def test_a_job_is_enqueued_once_per_key_and_found_again(
    engine: Engine,
    sessions: sessionmaker[Session],
    settings: Settings,
    store: Store,
    paper_batch: Detections,
) -> None:
    asked = Job(batch_id=store(paper_batch))
    idempotent = IdempotentRequest(key="k", principal="p", digest="d")

    def create() -> tuple[uuid.UUID, bool]:
        with sessions() as session:
            return create_job_once(
                session,
                settings=settings,
                asked=asked,
                idempotent=idempotent,
                answer=lambda job: job.id,
            )

    job_id, replayed = create()
    assert not replayed
    before = row_counts(engine)
    assert create() == (job_id, True)
    assert row_counts(engine) == before
    with sessions() as session:
        assert require_job(session, job_id).associator == "kmeans"
        with pytest.raises(ServiceProblem) as raised:
            require_job(session, uuid.uuid4())
    assert raised.value.status == 404
