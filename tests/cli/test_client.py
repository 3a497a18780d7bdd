"""The remote commands' HTTP client (`cli/client.py`): the key as a bearer, and every failure, a
refused connection or a problem from the server, as one line fit for a terminal. (The commands
against a served API: test_remote.py.)"""

from __future__ import annotations

import httpx
import pytest

from roadlink.cli.client import Remote, RemoteError, problem_line


def answering(handler: httpx.MockTransport) -> Remote:
    remote = Remote("http://roadlink.test/", "rl_abc_secret")
    remote.http = httpx.Client(base_url=remote.url, headers=remote.http.headers, transport=handler)
    return remote


def test_requests_carry_the_key_and_successes_come_back() -> None:
    seen: list[httpx.Request] = []

    def handler(request: httpx.Request) -> httpx.Response:
        seen.append(request)
        return httpx.Response(200, json={"ok": True})

    with answering(httpx.MockTransport(handler)) as remote:
        assert remote.url == "http://roadlink.test"  # no trailing slash
        assert remote.json("GET", "/v1/jobs") == {"ok": True}
    assert seen[0].headers["Authorization"] == "Bearer rl_abc_secret"
    assert "Authorization" not in Remote("http://x", None).http.headers


def test_a_problem_from_the_server_is_one_line() -> None:
    problem = {"title": "Not Found", "status": 404, "detail": "there is no job\n  42"}

    def handler(request: httpx.Request) -> httpx.Response:
        return httpx.Response(404, json=problem)

    with answering(httpx.MockTransport(handler)) as remote, pytest.raises(RemoteError) as raised:
        remote.request("GET", "/v1/jobs/42")
    assert str(raised.value) == "404 Not Found: there is no job 42"


def test_an_unreachable_server_is_one_line_naming_it() -> None:
    def handler(request: httpx.Request) -> httpx.Response:
        raise httpx.ConnectError("connection refused")

    with answering(httpx.MockTransport(handler)) as remote, pytest.raises(RemoteError) as raised:
        remote.request("GET", "/healthz")
    assert str(raised.value) == "cannot reach http://roadlink.test: connection refused"


@pytest.mark.parametrize(
    ("response", "line"),
    [
        (httpx.Response(422, json={"detail": "bad"}), "422 Unprocessable Entity: bad"),
        (
            httpx.Response(502, text="<html>\n<b>Bad gateway</b>\n</html>"),
            "502 Bad Gateway: <html> <b>Bad gateway</b> </html>",
        ),
        (httpx.Response(503), "503 Service Unavailable"),
        (httpx.Response(500, text="x" * 500), "500 Internal Server Error: " + "x" * 200),
        (
            httpx.Response(400, json=["not", "a", "problem"]),
            '400 Bad Request: ["not","a","problem"]',
        ),
    ],
)
def test_any_error_answer_is_one_line(response: httpx.Response, line: str) -> None:
    assert problem_line(response) == line
