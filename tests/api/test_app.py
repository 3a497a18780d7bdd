"""The application factory (`api/app.py`): what an app holds, which routes need a key, the rate
limit only where keys are required, operation ids that read well, and the OpenAPI document with
the schemas FastAPI cannot see. (The committed contract itself: test_openapi.py.)"""

from __future__ import annotations

import json
from types import SimpleNamespace

import pytest
from fastapi.testclient import TestClient

from roadlink.api.app import create_app, openapi_json, operation_id
from roadlink.api.ratelimit import TokenBuckets
from roadlink.settings import Settings


def app_for(**settings: object) -> TestClient:
    return TestClient(create_app(Settings(database_url="sqlite://", **settings)))  # type: ignore[arg-type]


def test_an_operation_is_named_by_its_tag_and_handler() -> None:
    route = SimpleNamespace(tags=["jobs", "other"], name="get_result")
    assert operation_id(route) == "jobs-get_result"  # type: ignore[arg-type]


@pytest.mark.parametrize(
    ("settings", "limited"),
    [
        ({}, True),
        ({"rate_limit_per_second": 0}, False),
        ({"auth": "disabled"}, False),
    ],
)
def test_keys_are_rate_limited_only_when_required_and_a_rate_is_set(
    settings: dict[str, object], limited: bool
) -> None:
    state = app_for(**settings).app.state  # type: ignore[attr-defined]
    assert isinstance(state.rate_limits, TokenBuckets) == limited
    if not limited:
        assert state.rate_limits is None


def test_v1_routes_need_a_key_health_does_not_and_pages_answer_for_themselves() -> None:
    client = app_for()
    refused = client.get("/v1/associators")
    assert refused.status_code == 401 and refused.headers["www-authenticate"].startswith("Bearer")
    assert refused.headers["content-type"] == "application/problem+json"
    assert client.get("/healthz").status_code == 200
    # The job page checks its own link tokens and says so to a browser, in HTML.
    page = client.get("/jobs/00000000-0000-0000-0000-000000000000")
    assert page.headers["content-type"].startswith("text/html")


def test_the_openapi_document_holds_the_batch_body_and_problem_schemas_sorted() -> None:
    app = create_app(Settings(database_url="sqlite://"))
    document = app.openapi()
    schemas = document["components"]["schemas"]
    assert {"BatchCreate", "ProblemDetail", "DetectionIn"} <= schemas.keys()
    assert list(schemas) == sorted(schemas)
    assert "$defs" not in schemas["BatchCreate"]
    assert app.openapi() is document  # built once
    assert all(not path.startswith("/jobs/") for path in document["paths"])  # pages: no schema
    text = openapi_json(app)
    assert text.endswith("}\n") and json.loads(text) == document
    assert text == json.dumps(document, indent=2, ensure_ascii=False) + "\n"
