"""Errors as RFC 9457 problem details (application/problem+json), naming the field and row.

The one place where problems become responses: the services' `ServiceProblem`, the API's own
`ApiProblem` (its subclass, with headers), invalid requests, HTTP errors and, outermost, any
exception no handler expected."""

from __future__ import annotations

import logging
import uuid
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from http import HTTPStatus
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel, ConfigDict, Field
from sqlalchemy.exc import DBAPIError, IntegrityError, OperationalError
from sqlalchemy.exc import TimeoutError as PoolTimeout
from starlette.exceptions import HTTPException as StarletteHTTPException
from starlette.routing import Match
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from roadlink.association.detections import Problem
from roadlink.logs import current_request_id
from roadlink.services.problems import ProblemItem, ServiceProblem

log = logging.getLogger("roadlink")

PROBLEM_MEDIA_TYPE = "application/problem+json"
TITLES = {413: "Content Too Large", 422: "Unprocessable Content"}


class ProblemDetail(BaseModel):
    """An error response (RFC 9457)."""

    model_config = ConfigDict(
        json_schema_extra={
            "examples": [
                {
                    "type": "about:blank",
                    "title": "Unprocessable Content",
                    "status": 422,
                    "detail": "2 detections are invalid",
                    "errors": [
                        {
                            "row": 3,
                            "field": "velocity",
                            "pointer": "/detections/2/velocity",
                            "message": "must be > 0, got -4.0",
                        }
                    ],
                }
            ]
        }
    )

    type: str = Field(default="about:blank", description="URI of the problem type.")
    title: str = Field(description="Short summary of the problem type (the HTTP reason).")
    status: int = Field(description="HTTP status code.")
    detail: str = Field(description="What happened here, and what to do about it.")
    instance: str | None = Field(default=None, description="The request path.")
    errors: list[ProblemItem] = Field(
        default_factory=list, description="Each thing wrong, with its row and field."
    )
    error_id: str | None = Field(
        default=None,
        description="For a failure of the server (5xx, or a conflict in the database): the id "
        "under which its log holds the details.",
    )
    request_id: str | None = Field(
        default=None,
        description="The request's id (its X-Request-ID, or the one the server gave it): every "
        "log line of the request carries it.",
    )


class ApiProblem(ServiceProblem):
    """A problem the API itself finds (a key, a rate limit, a body, a view too large to draw),
    raised anywhere in a request; it may carry headers for the answer (WWW-Authenticate,
    Retry-After)."""

    def __init__(
        self,
        status: int,
        detail: str,
        *,
        errors: Sequence[ProblemItem] = (),
        headers: dict[str, str] | None = None,
    ) -> None:
        super().__init__(status, detail, errors=errors)
        self.headers = headers


def parameter_problem(name: str, message: str) -> ApiProblem:
    """A 422 for one query parameter, named as a request validation error names it."""
    return ApiProblem(
        422,
        f"the request is invalid: {name}: {message}",
        errors=[ProblemItem(field=name, message=message)],
    )


def problem_response(
    request: Request,
    status: int,
    detail: str,
    errors: Sequence[ProblemItem] = (),
    headers: Mapping[str, str] | None = None,
    error_id: str | None = None,
) -> JSONResponse:
    """The problem+json response for `status`."""
    body = ProblemDetail(
        title=status_title(status),
        status=status,
        detail=detail,
        instance=request.url.path,
        errors=list(errors),
        error_id=error_id,
        request_id=current_request_id(),
    )
    return JSONResponse(
        body.model_dump(mode="json"),
        status_code=status,
        media_type=PROBLEM_MEDIA_TYPE,
        headers=dict(headers) if headers else None,
    )


def problems_from_detections(
    problems: Sequence[Problem], *, json_prefix: str | None = None
) -> list[ProblemItem]:
    """The core's validation problems as problem items; with a JSON body, pointers too."""
    items = []
    for p in problems:
        pointer = None
        if json_prefix is not None and p.row is not None:
            pointer = f"{json_prefix}/{p.row - 1}" + (f"/{p.field}" if p.field else "")
        items.append(ProblemItem(row=p.row, field=p.field, pointer=pointer, message=p.message))
    return items


def validation_item(
    location: Sequence[Any], message: str, *, under: str | None = None, pointer: bool = True
) -> ProblemItem:
    """The one translation of a pydantic validation error (its `loc` and `msg`) into a problem
    item: the field as a dotted path (below `under`, when the validated value sits there in the
    request), and, for a JSON document, the JSON Pointer to it."""
    path = [str(part) for part in location]
    field = ".".join([under, *path] if under else path) or None
    return ProblemItem(
        field=field, pointer="/" + "/".join(path) if pointer else None, message=message
    )


HTTP_METHODS = ("DELETE", "GET", "HEAD", "OPTIONS", "PATCH", "POST", "PUT")

# What FastAPI says, as a 400, of a body it could not decode at all.
FASTAPI_UNREADABLE_BODY = "There was an error parsing the body"

# Where FastAPI found a request parameter: the first part of a validation error's location.
PARAMETER_SOURCES = ("query", "path", "header")


def malformed_json(reason: str, *, document: str = "", position: int | None = None) -> ApiProblem:
    """The one answer to a body that is not JSON, on every endpoint: a 422 saying where (line,
    column and character, counted in `document`, the body as text) and why."""
    at = ""
    if position is not None:
        line = document.count("\n", 0, position) + 1
        column = position - document.rfind("\n", 0, position)
        at = f" at line {line}, column {column} (character {position})"
    message = f"the body is not valid JSON{at}: {reason}"
    return ApiProblem(
        422, f"the request is invalid: body: {message}", errors=[ProblemItem(message=message)]
    )


def _json_syntax_error(exc: RequestValidationError) -> ApiProblem | None:
    """FastAPI's error for a body its JSON parser refused, as `malformed_json`; else None."""
    errors = exc.errors()
    if len(errors) != 1 or errors[0].get("type") != "json_invalid":
        return None
    error = errors[0]
    where = [part for part in error.get("loc", ()) if isinstance(part, int)]
    reason = error.get("ctx", {}).get("error") or error.get("msg", "invalid")
    document = exc.body if isinstance(exc.body, str) else ""
    return malformed_json(reason, document=document, position=where[0] if where else None)


def _request_item(error: Mapping[str, Any]) -> ProblemItem:
    """A request validation error: a parameter is named by its name (no pointer), a body field
    by its path, the body as a whole by nothing."""
    location = [part for part in error.get("loc", ()) if part != "body"]
    message = error.get("msg", "invalid")
    if location and location[0] in PARAMETER_SOURCES:
        return validation_item(location[1:] or location[:1], message, pointer=False)
    if location:
        return validation_item(location, message)
    return ProblemItem(message=message)


def install_error_handlers(app: FastAPI) -> None:
    """Every error the app answers, in the one problem+json shape."""

    @app.exception_handler(ServiceProblem)
    async def _service_problem(request: Request, exc: ServiceProblem) -> JSONResponse:
        headers = exc.headers if isinstance(exc, ApiProblem) else None
        return problem_response(request, exc.status, exc.detail, exc.errors, headers)

    @app.exception_handler(RequestValidationError)
    async def _invalid_request(request: Request, exc: RequestValidationError) -> JSONResponse:
        syntax = _json_syntax_error(exc)
        if syntax is not None:
            return problem_response(request, syntax.status, syntax.detail, syntax.errors)
        items = [_request_item(error) for error in exc.errors()]
        detail = "; ".join(f"{i.field or 'body'}: {i.message}" for i in items[:5])
        return problem_response(request, 422, f"the request is invalid: {detail}", items)

    @app.exception_handler(StarletteHTTPException)
    async def _http_error(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        detail = exc.detail if isinstance(exc.detail, str) else HTTPStatus(exc.status_code).phrase
        headers = exc.headers
        if exc.status_code == 400 and detail == FASTAPI_UNREADABLE_BODY:
            # FastAPI's answer to a JSON body that is not even text (not UTF-8): malformed JSON
            # like any other, so the same documented 422 as its JSONDecodeError gets.
            problem = malformed_json("it is not UTF-8 text")
            return problem_response(request, problem.status, problem.detail, problem.errors)
        if exc.status_code == 405:
            headers = {**(headers or {}), "Allow": ", ".join(_allowed_methods(request))}
        return problem_response(request, exc.status_code, detail, headers=headers)


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route of the path takes. Starlette's own 405 names those of the first
    route that matched the path only, while FastAPI makes a route per method (GET and POST
    /v1/deployments are two). Each method is tried on the app's routes as they match a request."""
    return [
        method
        for method in HTTP_METHODS
        if any(
            route.matches({**request.scope, "method": method})[0] == Match.FULL
            for route in request.app.router.routes
        )
    ]


RETRY_AFTER_HEADER = {
    "Retry-After": {
        "description": "Seconds to wait before trying again.",
        "schema": {"type": "integer", "minimum": 1},
    }
}


def problem_responses(*statuses: int) -> dict[int | str, dict[str, Any]]:
    """OpenAPI `responses` entries for error statuses, all problem details (a 429 or 503 with
    its Retry-After)."""
    responses: dict[int | str, dict[str, Any]] = {}
    for status in statuses:
        response: dict[str, Any] = {
            "description": status_title(status),
            "content": {
                PROBLEM_MEDIA_TYPE: {"schema": {"$ref": "#/components/schemas/ProblemDetail"}}
            },
        }
        if status in (429, 503):
            response["headers"] = RETRY_AFTER_HEADER
        responses[status] = response
    return responses


def status_title(status: int) -> str:
    """The reason phrase of RFC 9110 (which renamed 413 and 422)."""
    return TITLES.get(status) or HTTPStatus(status).phrase


# How long a client should wait before retrying when the database is busy or unavailable.
RETRY_AFTER_SECONDS = 5

# What SQLite and PostgreSQL say when the database cannot take writes for now: a full disk, a
# read-only file or server, a lock held too long, a lost connection. All pass, or may pass.
_UNAVAILABLE_MESSAGES = (
    "database or disk is full",
    "readonly database",
    "read-only",
    "database is locked",
    "disk i/o error",
    "unable to open database file",
    "no space left",
    "server closed the connection",
    "connection refused",
    "terminating connection",
)


@dataclass(frozen=True)
class UnexpectedProblem:
    """The answer to an exception no handler expected: status, words, headers, and the id that
    the log line with its traceback carries."""

    status: int
    detail: str
    headers: dict[str, str]
    error_id: str


def problem_for(exc: BaseException) -> UnexpectedProblem:
    """The one translation of an unexpected exception, database errors included, into a problem.

    - the database unavailable for now (see `_UNAVAILABLE_MESSAGES`, or a connection error),
      or every connection of the pool busy for its whole timeout: 503 with Retry-After, since
      a retry will likely succeed;
    - a constraint the request broke in the database (a concurrent change): 409;
    - anything else: 500. Never the exception's text: it may hold paths, SQL or data.
    """
    error_id = uuid.uuid4().hex[:12]
    if isinstance(exc, IntegrityError):
        return UnexpectedProblem(
            409,
            "the request conflicts with a concurrent change in the database; "
            f"retry it (error id {error_id})",
            {},
            error_id,
        )
    if isinstance(exc, PoolTimeout):
        # Every connection of the pool stayed in use for the pool's whole timeout: a burst of
        # requests larger than the pool (or slow queries under load), not a fault of this one.
        return UnexpectedProblem(
            503,
            "the server is busy: every database connection stayed in use; "
            f"retry in a few seconds (error id {error_id})",
            {"Retry-After": str(RETRY_AFTER_SECONDS)},
            error_id,
        )
    if isinstance(exc, DBAPIError) and (exc.connection_invalidated or _unavailable(exc)):
        return UnexpectedProblem(
            503,
            "the database cannot take this request now (full, read-only, busy or unreachable); "
            f"retry in a few seconds (error id {error_id})",
            {"Retry-After": str(RETRY_AFTER_SECONDS)},
            error_id,
        )
    return UnexpectedProblem(
        500, f"the server failed; it logged the details under error id {error_id}", {}, error_id
    )


def _unavailable(exc: DBAPIError) -> bool:
    text = str(exc.orig).lower()
    return isinstance(exc, OperationalError) and any(m in text for m in _UNAVAILABLE_MESSAGES)


class ProblemsForEveryError:
    """The outermost layer: whatever fails anywhere inside (routes, dependencies, the other
    middleware), the client gets problem+json with an error id, and the log gets the traceback
    under the same id. Once a response has started, only the log can be told."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = False

        async def tracking_send(message: Message) -> None:
            nonlocal started
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, receive, tracking_send)
        except Exception as exc:
            problem = problem_for(exc)
            log.error(
                "error %s: %s %s failed with %s (answered %d)",
                problem.error_id,
                scope.get("method"),
                scope.get("path"),
                type(exc).__name__,
                problem.status,
                exc_info=exc,
            )
            if started:
                raise
            response = problem_response(
                Request(scope),
                problem.status,
                problem.detail,
                headers=problem.headers,
                error_id=problem.error_id,
            )
            await response(scope, receive, send)
