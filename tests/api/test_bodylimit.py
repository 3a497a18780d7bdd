"""Oversized request bodies (`api/bodylimit.py`): 413 before a declared body is read, and the
moment a chunked one passes the limit; smaller bodies reach the app whole."""

from __future__ import annotations

from collections.abc import Iterator

from starlette.applications import Starlette
from starlette.requests import Request
from starlette.responses import PlainTextResponse
from starlette.routing import Route
from starlette.testclient import TestClient

from roadlink.api.bodylimit import BodyLimitMiddleware

LIMIT = 10
reached: list[int] = []


async def echo_length(request: Request) -> PlainTextResponse:
    body = await request.body()
    reached.append(len(body))
    return PlainTextResponse(str(len(body)))


def client() -> TestClient:
    app = Starlette(routes=[Route("/", echo_length, methods=["POST"])])
    return TestClient(BodyLimitMiddleware(app, limit=LIMIT))


def chunks(n: int, size: int) -> Iterator[bytes]:
    for _ in range(n):
        yield b"x" * size


def test_a_body_within_the_limit_reaches_the_app_whole() -> None:
    reached.clear()
    response = client().post("/", content=b"x" * LIMIT)
    assert response.status_code == 200 and response.text == str(LIMIT)
    assert reached == [LIMIT]


def test_a_declared_body_over_the_limit_is_refused_unread() -> None:
    reached.clear()
    response = client().post("/", content=b"x" * (LIMIT + 1))
    assert response.status_code == 413
    assert response.headers["content-type"] == "application/problem+json"
    problem = response.json()
    assert problem["status"] == 413 and f"limit of {LIMIT} bytes" in problem["detail"]
    assert problem["instance"] == "/"
    assert reached == []


def test_a_chunked_body_is_refused_when_it_passes_the_limit() -> None:
    reached.clear()
    response = client().post("/", content=chunks(4, 4))
    assert response.status_code == 413 and "ROADLINK_MAX_BODY_BYTES" in response.json()["detail"]
    ok = client().post("/", content=chunks(2, 4))
    assert ok.status_code == 200 and ok.text == "8"
