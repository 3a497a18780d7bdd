"""The FastAPI application factory."""

from __future__ import annotations

import json
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import Depends, FastAPI
from fastapi.openapi.utils import get_openapi
from fastapi.routing import APIRoute
from sqlalchemy import Engine

from roadlink import __version__
from roadlink.api.auth import authorize, check_policy_covers
from roadlink.api.bodylimit import BodyLimitMiddleware
from roadlink.api.errors import (
    ProblemDetail,
    ProblemsForEveryError,
    install_error_handlers,
    problem_responses,
)
from roadlink.api.expired_idempotency_keys import forgetting_expired_keys
from roadlink.api.jobresults import JobResultCache
from roadlink.api.prometheus import ApiMetrics, RequestMetrics
from roadlink.api.ratelimit import TokenBuckets
from roadlink.api.requestids import HEADER, RequestIdMiddleware
from roadlink.api.routers import (
    associators,
    batches,
    deployments,
    health,
    jobs,
    live,
    live_page,
    pages,
    simulations,
    webhooks,
)
from roadlink.api.schemas import BatchCreate
from roadlink.api.stalls import StallWatch
from roadlink.db.engine import engine_for, make_session_factory
from roadlink.settings import Settings

DESCRIPTION = """\
Groups anonymous roadside sensor detections (position, velocity, timestamp) into one row per
vehicle, and scores the grouping when true labels are given.

Post detections to a deployment as a batch (JSON or CSV), run a job over one or more batches or
a time window, and read its result. Errors are RFC 9457 problem details naming the field and
the row at fault.

Every /v1 route needs an API key, `Authorization: Bearer <key>` (create one with
`roadlink keys create --scope admin|read|ingest`); the health routes are open.

Lists come a page at a time: follow `next` (or pass `next_cursor` as `cursor`) until it is null.
Send `X-Request-ID` (at most 128 letters, digits and `._:-`) to name a request in the service's
logs; every response echoes it (or the id the server made up), problems carry it as
`request_id`, and a job keeps the id of the request that created it.
"""

TAGS = [
    {"name": "deployments", "description": "Stretches of road and their sensors."},
    {"name": "batches", "description": "Uploads of detections (JSON or CSV)."},
    {"name": "jobs", "description": "Associations run by the workers, and their results."},
    {"name": "associators", "description": "The algorithms a job can use."},
    {"name": "simulations", "description": "Labelled detections from the paper's Algorithm 1."},
    {"name": "webhooks", "description": "Signed events of a deployment POSTed to its URLs."},
    {"name": "health", "description": "Liveness, readiness and Prometheus metrics."},
]


def operation_id(route: APIRoute) -> str:
    """`{tag}-{name}`, e.g. `jobs-get_result`, so that generated clients read well."""
    return f"{route.tags[0]}-{route.name}"


def create_app(settings: Settings | None = None, *, engine: Engine | None = None) -> FastAPI:
    """The API for `settings` (from the environment if not given).

    The schema must already be migrated (`roadlink migrate`, or `roadlink serve` does it).
    """
    settings = settings or Settings()
    engine = engine or engine_for(settings)
    app = FastAPI(
        title="roadlink",
        version=__version__,
        description=DESCRIPTION,
        openapi_tags=TAGS,
        generate_unique_id_function=operation_id,
        lifespan=_lifespan,
    )
    app.state.settings = settings
    app.state.engine = engine
    app.state.sessions = make_session_factory(engine)
    app.state.metrics = ApiMetrics(app.state.sessions, lease_seconds=settings.lease_seconds)
    app.state.stalls = StallWatch(app.state.metrics.registry, settings.stall_log_ms / 1000)
    app.state.job_results = JobResultCache()
    limited = settings.auth == "required" and settings.rate_limit_per_second > 0
    app.state.rate_limits = (
        TokenBuckets(settings.rate_limit_per_second, settings.rate_limit_burst) if limited else None
    )

    install_error_handlers(app)

    app.add_middleware(RequestMetrics, metrics=app.state.metrics)
    app.add_middleware(BodyLimitMiddleware, limit=settings.max_body_bytes)
    app.add_middleware(ProblemsForEveryError)
    # Added last: the outermost layer, so that every answer (a problem included) has the id.
    app.add_middleware(RequestIdMiddleware)
    protected = [
        m.router for m in (deployments, batches, jobs, live, associators, simulations, webhooks)
    ]
    check_policy_covers(protected)
    for router in protected:
        app.include_router(
            router,
            dependencies=[Depends(authorize)],
            responses=problem_responses(401, 403, 429),
        )
    app.include_router(health.router)  # open: probes and Prometheus carry no key
    # For browsers, outside /v1 and the schema; they check their own link tokens (routers/pages.py,
    # routers/live_page.py).
    app.include_router(pages.router)
    app.include_router(live_page.router)
    app.openapi = lambda: _openapi_with_batch_body(app)  # type: ignore[method-assign]
    return app


@asynccontextmanager
async def _lifespan(app: FastAPI) -> AsyncIterator[None]:
    async with forgetting_expired_keys(app), app.state.stalls.running():
        yield


def _openapi_with_batch_body(app: FastAPI) -> dict[str, Any]:
    """The OpenAPI document, with the JSON batch body's schema among the components.

    Batch uploads read the body themselves (JSON or CSV, validated once by the core), so FastAPI
    does not see `BatchCreate`; errors are declared as problem+json by reference. Both schemas
    are added here for the references to resolve.
    """
    if app.openapi_schema is None:
        document = get_openapi(
            title=app.title,
            version=app.version,
            description=app.description,
            routes=app.routes,
            tags=app.openapi_tags,
        )
        components = document.setdefault("components", {}).setdefault("schemas", {})
        for model in (BatchCreate, ProblemDetail):
            schema = model.model_json_schema(ref_template="#/components/schemas/{model}")
            for name, definition in schema.pop("$defs", {}).items():
                components.setdefault(name, definition)
            components[model.__name__] = schema
        document["components"]["schemas"] = dict(sorted(components.items()))
        _declare_request_id_header(document)
        app.openapi_schema = document
    return app.openapi_schema


def _declare_request_id_header(document: dict[str, Any]) -> None:
    """Every response carries X-Request-ID (api/requestids.py): say so on each."""
    header = {
        "description": "The request's id: the X-Request-ID sent, when fit to log (at most 128 "
        "letters, digits and `._:-`), else one the server made. Its log lines carry it.",
        "schema": {"type": "string"},
    }
    document["components"]["headers"] = {HEADER: header}
    reference = {"$ref": f"#/components/headers/{HEADER}"}
    for operations in document.get("paths", {}).values():
        for operation in operations.values():
            for response in operation.get("responses", {}).values():
                response.setdefault("headers", {})[HEADER] = reference


def openapi_json(app: FastAPI) -> str:
    """The OpenAPI document as committed in openapi/openapi.json (stable formatting)."""
    return json.dumps(app.openapi(), indent=2, ensure_ascii=False) + "\n"
