"""Simulations: a labelled batch generated with the paper's Algorithm 1."""

from __future__ import annotations

import dataclasses
from typing import cast

import numpy as np
from fastapi import APIRouter, Response
from pydantic import BaseModel, ValidationError

from roadlink.api.deps import SessionDep, SettingsDep
from roadlink.api.errors import ApiProblem, problem_responses, validation_item
from roadlink.api.resourcelinks import CREATED_HEADERS, set_location
from roadlink.api.schemas import BatchRead, SimulationCreate, batch_read
from roadlink.association.detections import Detections
from roadlink.db.json_columns import Sensor
from roadlink.services.batches import ParsedBatch, batch_job, store_batch
from roadlink.services.deployments import require_deployment
from roadlink.services.problems import ProblemItem
from roadlink.simulation import preset, simulate

# Algorithm 1 costs time per target and sensor; beyond this a request would hold an API thread
# for minutes (simulate locally with `roadlink simulate` and upload the CSV instead).
MAX_SIMULATED_DETECTIONS = 200_000

router = APIRouter(prefix="/v1/simulations", tags=["simulations"])


@router.post(
    "",
    name="create",
    status_code=201,
    response_model=BatchRead,
    responses={201: {"headers": CREATED_HEADERS}, **problem_responses(404, 413, 422)},
    summary="Simulate a labelled batch",
)
def create_simulation(
    body: SimulationCreate, session: SessionDep, settings: SettingsDep, response: Response
) -> BatchRead:
    """Generate detections with Algorithm 1 (a preset, changed by `config`, and a seed) and store
    them as a labelled batch of the deployment; with `associate`, its job is enqueued too."""
    deployment = require_deployment(session, body.deployment_id)
    overrides = cast(BaseModel, body.config).model_dump(exclude_none=True)
    declared = deployment.sensors
    if declared and "sensor_positions" not in overrides:
        overrides["sensor_positions"] = [s.position for s in declared]
    try:
        config = preset(body.preset, **overrides)
    except ValidationError as exc:
        items = [
            validation_item(e["loc"], e["msg"], under="config", pointer=False) for e in exc.errors()
        ]
        raise ApiProblem(422, "the simulation settings are invalid", errors=items) from None
    expected = config.n_targets * len(config.sensor_positions) * (1 + config.false_alarm_rate)
    if expected > MAX_SIMULATED_DETECTIONS:
        raise ApiProblem(
            422,
            f"this simulation would make about {expected:.0f} detections, more than the "
            f"{MAX_SIMULATED_DETECTIONS} one request may generate; use `roadlink simulate` "
            "and upload the CSV in batches",
            errors=[ProblemItem(field="config.n_targets", message="too many detections")],
        )
    detections = simulate(config, seed=body.seed).detections
    if declared:
        detections = _with_declared_sensor_ids(detections, declared)
    batch = store_batch(
        session,
        settings=settings,
        deployment_id=deployment.id,
        batch=ParsedBatch(detections, "simulation", body.associate),
    )
    session.commit()
    set_location(response, f"/v1/batches/{batch.id}")
    return batch_read(batch, batch_job(session, batch))


def _with_declared_sensor_ids(detections: Detections, declared: list[Sensor]) -> Detections:
    """Name each simulated detection's sensor as the deployment does, or 422 when the
    simulated sensors are not the declared ones."""
    by_position = {s.position: s.sensor_id for s in declared}
    unknown = sorted({float(p) for p in detections.sensor_positions} - by_position.keys())
    if unknown:
        raise ApiProblem(
            422,
            f"the deployment declares no sensor at position(s) {unknown}",
            errors=[ProblemItem(field="config.sensor_positions", message="not declared sensors")],
        )
    names = np.array([by_position[float(p)] for p in detections.position], dtype=object)
    # Every other column as simulated, the lane, length and class reported included.
    return dataclasses.replace(detections, sensor_id=names)
