"""The Idempotency-Key header (`api/idempotency_header.py`): declared once with its rules (1 to 200
characters), and the request it makes idempotent: its key, its sender, the digest of its content
type and body."""

from __future__ import annotations

from typing import Any

from fastapi import Depends, FastAPI, Request
from fastapi.testclient import TestClient

from roadlink.api.auth import Principal
from roadlink.api.errors import install_error_handlers
from roadlink.api.idempotency_header import IdempotencyDep, media_type
from roadlink.db.models import ApiKeyScope
from roadlink.services.idempotency import request_digest


def as_sender(request: Request) -> None:
    """What `auth.authorize` leaves on the request: its caller."""
    request.state.principal = Principal(id="key-1", scope=ApiKeyScope.ADMIN)


def client() -> TestClient:
    app = FastAPI(dependencies=[Depends(as_sender)])
    install_error_handlers(app)

    @app.post("/things")
    def create(request: Request, idempotent: IdempotencyDep) -> dict[str, Any] | None:
        return None if idempotent is None else vars(idempotent)

    return TestClient(app)


def test_without_the_header_the_request_is_not_idempotent() -> None:
    response = client().post("/things", json={"a": 1})
    assert response.status_code == 200 and response.json() is None


def test_the_request_is_scoped_by_key_sender_and_digest() -> None:
    response = client().post(
        "/things",
        content=b'{"b": 2,  "a": 1}',
        headers={"Idempotency-Key": "retry-1", "content-type": "application/json; charset=utf-8"},
    )
    assert response.json() == {
        "key": "retry-1",
        "principal": "key-1",
        "digest": request_digest("application/json", b'{"a":1,"b":2}'),
    }


def test_an_empty_or_overlong_key_is_a_problem_naming_the_header() -> None:
    for key in ("", "k" * 201):
        response = client().post("/things", json={}, headers={"Idempotency-Key": key})
        assert response.status_code == 422, key
        assert [e["field"] for e in response.json()["errors"]] == ["Idempotency-Key"]
    assert client().post("/things", json={}, headers={"Idempotency-Key": "k" * 200}).is_success


def test_the_media_type_is_the_content_type_without_its_parameters() -> None:
    def of(headers: dict[str, str]) -> str:
        scope = {
            "type": "http",
            "headers": [(k.lower().encode(), v.encode()) for k, v in headers.items()],
        }
        return media_type(Request(scope))

    assert of({"Content-Type": "Text/CSV; charset=utf-8"}) == "text/csv"
    assert of({}) == ""
