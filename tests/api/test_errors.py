"""Problem details (`api/errors.py`): every error an app answers, in the one problem+json shape,
from the services' problems, the API's own, invalid requests, HTTP errors and, outermost, any
exception no handler expected (with an error id that the log carries, never its text)."""

from __future__ import annotations

import json
import logging
import sqlite3
from pathlib import Path
from typing import Annotated, Any

import httpx
import pytest
from fastapi import FastAPI, Query
from fastapi.testclient import TestClient
from pydantic import BaseModel
from sqlalchemy import create_engine, text
from sqlalchemy.exc import IntegrityError, OperationalError

from roadlink.api.errors import (
    PROBLEM_MEDIA_TYPE,
    RETRY_AFTER_SECONDS,
    ApiProblem,
    ProblemsForEveryError,
    install_error_handlers,
    problem_for,
    problem_responses,
    problems_from_detections,
    status_title,
    validation_item,
)
from roadlink.association.detections import Problem
from roadlink.services.problems import ProblemItem, ServiceProblem

OPENAPI = Path(__file__).resolve().parents[2] / "openapi" / "openapi.json"


class Body(BaseModel):
    name: str
    count: int


def app_raising(exc: Exception) -> TestClient:
    """An app with the error handlers, whose routes raise `exc`, validate a query parameter and
    a JSON body."""
    app = FastAPI()
    install_error_handlers(app)
    app.add_middleware(ProblemsForEveryError)

    @app.get("/raise")
    def raising() -> None:
        raise exc

    @app.get("/query")
    def query(limit: Annotated[int, Query(ge=1)]) -> int:
        return limit

    @app.post("/body")
    def body(payload: Body) -> str:
        return payload.name

    return TestClient(app, raise_server_exceptions=False)


def problem(response: httpx.Response, status: int) -> dict[str, Any]:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == PROBLEM_MEDIA_TYPE
    return dict(response.json())


def test_a_service_problem_is_answered_with_its_status_detail_and_items():
    item = ProblemItem(row=2, field="velocity", message="must be > 0")
    body = problem(
        app_raising(ServiceProblem(404, "no such thing", errors=[item])).get("/raise"), 404
    )
    assert body == {
        "type": "about:blank",
        "title": "Not Found",
        "status": 404,
        "detail": "no such thing",
        "instance": "/raise",
        "errors": [{"row": 2, "field": "velocity", "pointer": None, "message": "must be > 0"}],
        "error_id": None,
        # This bare app has no RequestIdMiddleware (tests/api/test_requestids.py has it).
        "request_id": None,
    }


def test_an_api_problem_carries_its_headers():
    raised = ApiProblem(429, "slow down", headers={"Retry-After": "3"})
    response = app_raising(raised).get("/raise")
    assert problem(response, 429)["detail"] == "slow down"
    assert response.headers["Retry-After"] == "3"


def test_an_invalid_parameter_is_named_and_an_invalid_body_field_pointed_at():
    client = app_raising(RuntimeError())
    query = problem(client.get("/query", params={"limit": 0}), 422)
    assert [(e["field"], e["pointer"]) for e in query["errors"]] == [("limit", None)]
    assert str(query["detail"]).startswith("the request is invalid: limit: ")
    body = problem(client.post("/body", json={"name": "x", "count": "many"}), 422)
    assert [(e["field"], e["pointer"]) for e in body["errors"]] == [("count", "/count")]
    whole = problem(
        client.post("/body", content=b"[", headers={"content-type": "application/json"}), 422
    )
    assert whole["title"] == "Unprocessable Content"


def test_http_errors_are_problems_too():
    client = app_raising(RuntimeError())
    assert problem(client.get("/nowhere"), 404)["detail"] == "Not Found"
    assert problem(client.delete("/raise"), 405)["title"] == "Method Not Allowed"


@pytest.mark.parametrize(
    ("exc", "status"),
    [
        (RuntimeError("a bug with /secret/path in it"), 500),
        (IntegrityError("INSERT", {}, sqlite3.IntegrityError("UNIQUE constraint failed")), 409),
        (OperationalError("INSERT", {}, sqlite3.OperationalError("database is locked")), 503),
        (OperationalError("SELECT", {}, sqlite3.OperationalError("no such table: job")), 500),
    ],
)
def test_an_unexpected_exception_is_a_problem_with_an_id_the_log_carries(
    exc: Exception, status: int, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.ERROR, logger="roadlink")
    response = app_raising(exc).get("/raise")
    body = problem(response, status)
    error_id = str(body["error_id"])
    assert len(error_id) == 12 and error_id in str(body["detail"])
    assert "secret" not in response.text and "sqlite" not in response.text.lower()
    logged = [r for r in caplog.records if error_id in r.getMessage()]
    assert len(logged) == 1 and logged[0].exc_info is not None
    assert f"answered {status}" in logged[0].getMessage()
    assert ("Retry-After" in response.headers) == (status == 503)


def test_the_database_unavailable_for_now_is_a_503_to_retry():
    for message in ("database or disk is full", "attempt to write a readonly database"):
        unavailable = problem_for(OperationalError("x", {}, sqlite3.OperationalError(message)))
        assert unavailable.status == 503
        assert unavailable.headers == {"Retry-After": str(RETRY_AFTER_SECONDS)}
    lost = OperationalError("x", {}, Exception("whatever"), connection_invalidated=True)
    assert problem_for(lost).status == 503
    other = problem_for(ValueError("x"))
    assert other.status == 500 and other.headers == {} and other.error_id in other.detail
    assert problem_for(ValueError()).error_id != other.error_id


def test_a_connection_pool_busy_for_its_whole_timeout_is_a_503_to_retry(tmp_path: Path):
    # A real pool of one connection, held elsewhere: the route's checkout times out.
    engine = create_engine(
        f"sqlite:///{tmp_path / 'pool.db'}", pool_size=1, max_overflow=0, pool_timeout=0.1
    )
    app = FastAPI()
    install_error_handlers(app)
    app.add_middleware(ProblemsForEveryError)

    @app.get("/count")
    def count() -> int:
        with engine.connect() as connection:
            return int(connection.execute(text("SELECT 1")).scalar_one())

    client = TestClient(app, raise_server_exceptions=False)
    assert client.get("/count").json() == 1
    with engine.connect():
        response = client.get("/count")
    body = problem(response, 503)
    assert "busy" in str(body["detail"])
    assert response.headers["Retry-After"] == str(RETRY_AFTER_SECONDS)
    assert client.get("/count").json() == 1  # the connection back, the route answers again
    engine.dispose()


def test_detection_problems_point_into_a_json_body_only():
    problems = [
        Problem(row=3, field="velocity", message="must be > 0"),
        Problem(None, None, "empty"),
    ]
    items = problems_from_detections(problems, json_prefix="/detections")
    assert [(i.row, i.field, i.pointer) for i in items] == [
        (3, "velocity", "/detections/2/velocity"),
        (None, None, None),
    ]
    assert problems_from_detections(problems)[0].pointer is None  # CSV: rows, not pointers


def test_a_validation_error_becomes_a_field_path_and_pointer():
    item = validation_item(("params", "gate_cost"), "must be > 0", under="associate")
    assert (item.field, item.pointer) == ("associate.params.gate_cost", "/params/gate_cost")
    assert validation_item(("t",), "required", pointer=False).pointer is None
    assert validation_item((), "invalid").field is None


def test_titles_follow_rfc_9110_and_responses_declare_problem_json():
    assert [status_title(s) for s in (413, 422, 404)] == [
        "Content Too Large",
        "Unprocessable Content",
        "Not Found",
    ]
    declared = problem_responses(401, 413)
    assert declared[413]["description"] == "Content Too Large"
    assert declared[401]["content"][PROBLEM_MEDIA_TYPE]["schema"] == {
        "$ref": "#/components/schemas/ProblemDetail"
    }


def test_malformed_json_is_a_422_saying_where_on_every_route_that_takes_json(
    client: TestClient, deployment: dict[str, Any]
) -> None:
    """One answer for a body that is not JSON, whoever parses it (FastAPI, or the batch
    upload's own reader): a 422 naming line, column and character."""
    contract = json.loads(OPENAPI.read_text())
    routes = [
        (method, path)
        for path, operations in contract["paths"].items()
        for method, operation in operations.items()
        if "application/json" in operation.get("requestBody", {}).get("content", {})
    ]
    assert ("post", "/v1/deployments/{deployment_id}/batches") in routes and len(routes) >= 5
    for method, path in routes:
        url = path.replace("{deployment_id}", deployment["id"])
        response = client.request(
            method, url, content=b'{"a":\n @}', headers={"content-type": "application/json"}
        )
        answer = problem(response, 422)
        message = "the body is not valid JSON at line 2, column 2 (character 7)"
        assert answer["errors"][0]["message"].startswith(message), (method, path, answer)
        assert answer["detail"].startswith(f"the request is invalid: body: {message}")
