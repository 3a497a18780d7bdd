"""Liveness, readiness and Prometheus metrics."""

from __future__ import annotations

from fastapi import APIRouter, Request, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from sqlalchemy import Engine

from roadlink.api.errors import RETRY_AFTER_SECONDS, ApiProblem, problem_responses
from roadlink.api.schemas import HealthRead, ReadinessRead
from roadlink.db.engine import check_writable
from roadlink.db.migrate import current_revision, head_revision

router = APIRouter(tags=["health"])


@router.get("/healthz", name="live", response_model=HealthRead, summary="Liveness")
async def healthz() -> HealthRead:
    """The process is up and answering (on the event loop itself: no thread, no database)."""
    return HealthRead()


@router.get(
    "/readyz",
    name="ready",
    response_model=ReadinessRead,
    responses=problem_responses(503),
    summary="Readiness",
)
def readyz(request: Request) -> ReadinessRead:
    """The database answers, its schema is at the newest migration, and it takes writes (a
    write rolled back at once); 503 otherwise."""
    engine: Engine = request.app.state.engine
    try:
        revision = current_revision(engine)
    except Exception as exc:
        raise ApiProblem(
            503, f"the database does not answer: {type(exc).__name__}: {exc}"
        ) from None
    head = head_revision()
    if revision != head:
        raise ApiProblem(
            503,
            f"the database schema is at revision {revision}, not {head}: run `roadlink migrate`",
        )
    try:
        check_writable(engine)
    except Exception as exc:
        raise ApiProblem(
            503,
            f"the database answers but does not take writes: {type(exc).__name__}: {exc}",
            headers={"Retry-After": str(RETRY_AFTER_SECONDS)},
        ) from None
    return ReadinessRead(database=engine.dialect.name, revision=revision or "")


@router.get(
    "/metrics",
    name="metrics",
    response_class=Response,
    responses={
        200: {"description": "Prometheus text format.", "content": {CONTENT_TYPE_LATEST: {}}}
    },
    summary="Prometheus metrics",
)
def metrics(request: Request) -> Response:
    """Requests, jobs by state, queue depth and job durations."""
    return Response(
        generate_latest(request.app.state.metrics.registry), media_type=CONTENT_TYPE_LATEST
    )
