"""Deployments: stretches of road and their sensors."""

from __future__ import annotations

import uuid

from fastapi import APIRouter, Request, Response

from roadlink.api.auth import actor_of
from roadlink.api.deps import SessionDep
from roadlink.api.errors import problem_responses
from roadlink.api.pagination import LINK_HEADER, CursorQuery, LimitQuery, decode_cursor, page_of
from roadlink.api.resourcelinks import CREATED_HEADERS, set_location
from roadlink.api.schemas import DeploymentCreate, DeploymentPage, DeploymentRead
from roadlink.db import listings, repository
from roadlink.db.json_columns import Sensor
from roadlink.services.deployments import require_deployment
from roadlink.services.lifecycle import delete_deployment as delete_stored_deployment

router = APIRouter(prefix="/v1/deployments", tags=["deployments"])


@router.post(
    "",
    name="create",
    status_code=201,
    response_model=DeploymentRead,
    responses={201: {"headers": CREATED_HEADERS}, **problem_responses(413, 422)},
    summary="Create a deployment",
)
def create_deployment(
    body: DeploymentCreate, session: SessionDep, response: Response
) -> DeploymentRead:
    """A stretch of road. Declare its sensors to have detections of unknown sensors rejected."""
    sensors = None
    if body.sensors:
        in_road_order = sorted(body.sensors, key=lambda s: s.position)
        sensors = [Sensor(s.sensor_id, s.position) for s in in_road_order]
    deployment = repository.create_deployment(session, name=body.name, sensors=sensors)
    session.commit()
    set_location(response, f"/v1/deployments/{deployment.id}")
    return DeploymentRead.model_validate(deployment)


@router.get(
    "",
    name="list",
    response_model=DeploymentPage,
    responses={200: {"headers": LINK_HEADER}, **problem_responses(422)},
    summary="List deployments",
)
def list_deployments(
    session: SessionDep,
    request: Request,
    response: Response,
    limit: LimitQuery = 100,
    cursor: CursorQuery = None,
) -> DeploymentPage:
    """Deployments, oldest first, a page at a time (follow `next`)."""
    after = decode_cursor("deployments", cursor)
    found = listings.list_deployments(session, after=after, limit=limit)
    items, next_cursor, link = page_of("deployments", found, limit, request, response)
    return DeploymentPage(
        items=[DeploymentRead.model_validate(d) for d in items], next_cursor=next_cursor, next=link
    )


@router.get(
    "/{deployment_id}",
    name="get",
    response_model=DeploymentRead,
    responses=problem_responses(404, 422),
    summary="Get a deployment",
)
def get_deployment(deployment_id: uuid.UUID, session: SessionDep) -> DeploymentRead:
    """One deployment."""
    return DeploymentRead.model_validate(require_deployment(session, deployment_id))


@router.delete(
    "/{deployment_id}",
    name="delete",
    status_code=204,
    responses=problem_responses(404, 409, 422),
    summary="Delete a deployment and all its data",
)
def delete_deployment(deployment_id: uuid.UUID, request: Request, session: SessionDep) -> Response:
    """Delete the deployment with its batches, detections, jobs, results and webhooks. 409
    while one of its jobs is queued or running. Audited in the log."""
    delete_stored_deployment(session, deployment_id=deployment_id, actor=actor_of(request))
    session.commit()
    return Response(status_code=204)
