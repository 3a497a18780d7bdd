"""Jobs: associations run by the workers, their progress and their results."""

from __future__ import annotations

import uuid
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Annotated, Literal

from fastapi import APIRouter, FastAPI, Path, Query, Request, Response
from sqlalchemy.orm import Session, sessionmaker
from starlette.concurrency import run_in_threadpool

from roadlink.api.deps import SessionDep, SessionFactoryDep, SettingsDep
from roadlink.api.errors import ApiProblem, problem_responses
from roadlink.api.idempotency_header import IdempotencyDep
from roadlink.api.jobresults import SucceededJobDep, unfinished_detail
from roadlink.api.pagelinks import (
    DEFAULT_LIFETIME_SECONDS,
    ExpiresInQuery,
    page_link,
    page_token,
    public_url,
)
from roadlink.api.pagination import (
    LINK_HEADER,
    CursorQuery,
    LimitQuery,
    aware_time,
    date_time_or_null,
    decode_cursor,
    page_of,
)
from roadlink.api.resourcelinks import CREATED_HEADERS, set_location
from roadlink.api.schemas import (
    AssociationResultRead,
    JobCreate,
    JobPage,
    JobRead,
    PageLinkRead,
    PositionsRead,
    TargetPositionRead,
    TargetTrajectoryRead,
)
from roadlink.association.localisation import (
    positions_at,
    published_trajectory,
    sample_trajectory,
    target_index,
)
from roadlink.db import listings, repository
from roadlink.db.models import Job, JobState
from roadlink.plots import PlotFormat, PlotKind
from roadlink.queue.transitions import cancel_job
from roadlink.queue.wakeup import FinishedJobs
from roadlink.services.jobs import create_job_once, require_job
from roadlink.services.problems import ProblemItem
from roadlink.services.waiting import wait_for_job
from roadlink.settings import Settings


@asynccontextmanager
async def _listen_for_finished_jobs(app: FastAPI) -> AsyncIterator[None]:
    finished = FinishedJobs(app.state.settings.database_url)
    finished.start()
    app.state.finished_jobs = finished
    try:
        yield
    finally:
        finished.close()


router = APIRouter(prefix="/v1/jobs", tags=["jobs"], lifespan=_listen_for_finished_jobs)

MATRIX_CSV_EXAMPLE = (
    "target,S1_detection_id,S1_velocity,S1_timestamp,S2_detection_id,S2_velocity,S2_timestamp\n"
    "T1,d1,30.2,12.4,d2,30.5,15.7\n"
)


@router.post(
    "",
    name="create",
    status_code=202,
    response_model=JobRead,
    responses={202: {"headers": CREATED_HEADERS}, **problem_responses(404, 413, 422)},
    summary="Enqueue an association job",
)
def create_job(
    body: JobCreate,
    request: Request,
    response: Response,
    session: SessionDep,
    settings: SettingsDep,
    idempotent: IdempotencyDep,
) -> JobRead:
    """Associate one batch, several batches of one deployment, or a deployment's detections in
    the time window [start, end) (either end may be left open). With an Idempotency-Key, a retry
    returns the job the first request created."""
    job, replayed = create_job_once(
        session,
        settings=settings,
        asked=body,
        idempotent=idempotent,
        answer=JobRead.model_validate,
    )
    if replayed:
        response.headers["Idempotent-Replayed"] = "true"
    set_location(response, f"/v1/jobs/{job.id}")
    return job


@router.get(
    "",
    name="list",
    response_model=JobPage,
    responses={200: {"headers": LINK_HEADER}, **problem_responses(422)},
    summary="List jobs",
)
def list_jobs(
    session: SessionDep,
    request: Request,
    response: Response,
    deployment_id: uuid.UUID | None = Query(default=None, description="Only this deployment's."),
    state: JobState | None = Query(default=None, description="Only jobs in this state."),
    created_since: str | None = Query(
        default=None,
        description="Only jobs created at or after this time: ISO 8601 with a time zone, e.g. "
        "2026-01-01T00:00:00Z.",
        json_schema_extra=date_time_or_null,
    ),
    limit: LimitQuery = 100,
    cursor: CursorQuery = None,
) -> JobPage:
    """Jobs, newest first, a page at a time (follow `next`)."""
    after = decode_cursor("jobs", cursor)
    since = None if created_since is None else aware_time("created_since", created_since)
    found = listings.list_jobs(
        session,
        deployment_id=deployment_id,
        state=state,
        created_since=since,
        after=after,
        limit=limit,
    )
    items, next_cursor, link = page_of("jobs", found, limit, request, response)
    return JobPage(
        items=[JobRead.model_validate(j) for j in items], next_cursor=next_cursor, next=link
    )


@router.get(
    "/{job_id}",
    name="get",
    response_model=JobRead,
    responses=problem_responses(404, 422),
    summary="Get a job's status and progress",
)
def get_job(job_id: uuid.UUID, session: SessionDep) -> JobRead:
    """State (queued, running, succeeded, failed, cancelled), progress and attempts."""
    return JobRead.model_validate(require_job(session, job_id))


@router.get(
    "/{job_id}/result",
    name="get_result",
    response_model=AssociationResultRead,
    responses={
        200: {
            "description": "The association result (JSON), or with ?format=csv the target x "
            "sensor matrix.",
            "content": {"text/csv": {"schema": {"type": "string"}, "example": MATRIX_CSV_EXAMPLE}},
        },
        **problem_responses(404, 409, 422),
    },
    summary="Get a job's result",
)
async def get_result(
    job_id: uuid.UUID,
    request: Request,
    settings: SettingsDep,
    sessions: SessionFactoryDep,
    wait: Annotated[
        float,
        Query(
            ge=0,
            description="Wait up to this many seconds for an unfinished job to finish "
            "(capped at ROADLINK_MAX_WAIT_SECONDS), so no polling loop is needed.",
        ),
    ] = 0.0,
    format: Annotated[
        Literal["json", "csv"],
        Query(description="json: the result document; csv: the target x sensor matrix."),
    ] = "json",
) -> Response:
    """The result of a succeeded job: the same document `roadlink associate --json` prints for
    the same detections and parameters. 409 while the job is unfinished (or if it failed or was
    cancelled)."""
    stored: list[tuple[str, str] | None] = []  # the result, read with the job that succeeded
    job = await wait_for_job(
        job_id,
        wait=wait,
        max_wait=settings.max_wait_seconds,
        read_job=lambda: run_in_threadpool(_read_job_and_result, sessions, job_id, stored),
        finished_jobs=getattr(request.app.state, "finished_jobs", None),
        client_gone=request.is_disconnected,
    )
    if job.state != JobState.SUCCEEDED:
        raise ApiProblem(409, unfinished_detail(job))
    if stored[-1] is None:  # succeeded without a result cannot happen: both commit together
        raise ApiProblem(500, f"job {job_id} succeeded but its result is missing")
    result_json, matrix_csv = stored[-1]
    if format == "csv":
        return Response(matrix_csv, media_type="text/csv")
    return Response(result_json, media_type="application/json")


PLOT_MEDIA_TYPES = {"png": "image/png", "svg": "image/svg+xml"}
# A succeeded job's result never changes; it is the caller's own data, so caches stay private.
RESULT_CACHE_CONTROL = "private, max-age=86400"


@router.get(
    "/{job_id}/plot",
    name="get_plot",
    response_class=Response,
    responses={
        200: {
            "description": "The plot, as PNG or SVG.",
            "content": {
                "image/png": {"schema": {"type": "string", "format": "binary"}},
                "image/svg+xml": {"schema": {"type": "string"}},
            },
        },
        **problem_responses(404, 409, 413, 422),
    },
    summary="Plot a job's result",
)
def get_plot(
    job: SucceededJobDep,
    kind: Annotated[
        PlotKind,
        Query(
            description="time-space: position against time, one line per target; "
            "backprojected: the paper's (t', v) scatter coloured by group."
        ),
    ] = "time-space",
    format: Annotated[PlotFormat, Query(description="png or svg.")] = "png",
) -> Response:
    """The plot `roadlink associate --plot` draws for the same detections. When they are
    labelled, the wrongly grouped ones are ringed in red. In SVG each target is a group with id
    `target-T<k>`, and the highlights are the groups `unassigned` and `wrongly-grouped`. 409
    while the job is unfinished."""
    return Response(
        job.plot(kind, format),
        media_type=PLOT_MEDIA_TYPES[format],
        headers={"Cache-Control": RESULT_CACHE_CONTROL},
    )


@router.get(
    "/{job_id}/positions",
    name="get_positions",
    response_model=PositionsRead,
    # A vehicle's length and class appear only where the detections report them.
    response_model_exclude_unset=True,
    responses=problem_responses(404, 409, 413, 422),
    summary="Where every target is at a time",
)
def get_positions(
    job: SucceededJobDep,
    t: Annotated[
        float, Query(allow_inf_nan=False, description="The time, in the detections' units.")
    ],
) -> PositionsRead:
    """Every target on the observed road at time t (between its first and last sensor pass),
    with its position and velocity estimated by cubic Hermite interpolation through its passes.
    Targets before their first or after their last pass are not listed; where detections
    report them, each target's length and class. 409 while the job is unfinished."""
    n_targets = len(job.trajectories)
    return PositionsRead(
        time=t,
        targets=[
            TargetPositionRead(
                target=p.target,
                position=p.position,
                velocity=p.velocity,
                **job.vehicle_features[target_index(p.target, n_targets)],
            )
            for p in positions_at(job.trajectories, t)
        ],
    )


@router.get(
    "/{job_id}/targets/{target}",
    name="get_target",
    response_model=TargetTrajectoryRead,
    # A vehicle's length and class appear only where the detections report them.
    response_model_exclude_unset=True,
    responses=problem_responses(404, 409, 413, 422),
    summary="One target's trajectory, travel times and mean speeds",
)
def get_target(
    job: SucceededJobDep,
    target: Annotated[str, Path(description="The target as the result names it: T1, T2, ...")],
    step: Annotated[
        float | None,
        Query(
            gt=0,
            allow_inf_nan=False,
            description="Sample the track every `step` time units (default: 100 intervals "
            "from the first to the last pass; at most 100,000 samples).",
        ),
    ] = None,
) -> TargetTrajectoryRead:
    """A target's sensor passes, the travel time and mean speed between consecutive sensors,
    and its track (position and velocity by cubic Hermite interpolation) sampled from its first
    to its last pass. 404 for a target the result does not have."""
    try:
        index = target_index(target, len(job.trajectories))
    except KeyError as exc:
        raise ApiProblem(404, f"job {job.job_id} has no target: {exc.args[0]}") from None
    trajectory = job.trajectories[index]
    try:
        sampled = sample_trajectory(trajectory, step=step)
    except ValueError as exc:
        raise ApiProblem(
            422, str(exc), errors=[ProblemItem(field="step", message=str(exc))]
        ) from None
    return TargetTrajectoryRead.model_validate(
        {**published_trajectory(sampled), **job.vehicle_features[index]}
    )


@router.post(
    "/{job_id}/page-link",
    name="create_page_link",
    status_code=201,
    response_model=PageLinkRead,
    responses={201: {"headers": CREATED_HEADERS}, **problem_responses(404, 422)},
    summary="Make a link to a job's page for a browser",
)
def create_page_link(
    job_id: uuid.UUID,
    request: Request,
    response: Response,
    session: SessionDep,
    settings: SettingsDep,
    expires_in: ExpiresInQuery = DEFAULT_LIFETIME_SECONDS,
) -> PageLinkRead:
    """A link to the job's page (`/jobs/{job_id}`: status and progress while it runs, then the
    plot, the metrics and the targets) that opens in a browser without an API key. The link
    carries a token signed for this job only; it stops working when it expires or when the key
    that asked for it is revoked. Anyone holding the link can read the page until then, so
    share it as you would the result."""
    require_job(session, job_id)
    return page_link(
        request,
        response,
        session,
        url=page_url(settings, job_id),
        sign=lambda key, expires: page_token(key, job_id, expires),
        expires_in=expires_in,
    )


@router.post(
    "/{job_id}/cancel",
    name="cancel",
    response_model=JobRead,
    responses=problem_responses(404, 409, 422),
    summary="Cancel a job",
)
def cancel(job_id: uuid.UUID, session: SessionDep) -> JobRead:
    """Cancel a queued or running job (a running one stops at its next progress report and
    stores nothing). Cancelling a cancelled job is a no-op; a finished one is 409."""
    job = require_job(session, job_id)
    if job.state == JobState.CANCELLED:
        return JobRead.model_validate(job)
    if not cancel_job(session, job_id=job_id):
        session.rollback()
        job = require_job(session, job_id)
        if job.state != JobState.CANCELLED:
            raise ApiProblem(
                409, f"job {job_id} has already {job.state}; there is nothing to cancel"
            )
    session.commit()
    session.expire_all()
    return JobRead.model_validate(require_job(session, job_id))


def page_url(settings: Settings, job_id: uuid.UUID) -> str:
    """The job page's address (`pagelinks.public_url`)."""
    return public_url(settings, f"/jobs/{job_id}")


def _read_job_and_result(
    sessions: sessionmaker[Session], job_id: uuid.UUID, stored: list[tuple[str, str] | None]
) -> Job | None:
    """The job, and when it has succeeded its stored result appended to `stored`, in one read
    (one hop to the thread pool, not two, between a job's finish and its waiting request's
    answer)."""
    with sessions() as session:
        job = repository.get_job(session, job_id=job_id)
        if job is not None and job.state == JobState.SUCCEEDED:
            result = repository.get_job_result(session, job_id=job_id)
            stored.append(None if result is None else (result.result_json, result.matrix_csv))
        return job
