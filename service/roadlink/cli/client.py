"""The HTTP client the remote commands share: one httpx client per command, with the API key,
and every failure (a refused connection, a problem from the server) as one `RemoteError` line."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    import httpx

# httpx is imported by the remote commands when they run: importing it costs every command
# (`roadlink associate` on a paper-size file too) about 0.1 s.

DEFAULT_URL = "http://127.0.0.1:8000"
# Longer than the slowest answer we ask for: a batch upload of the largest body the service
# takes, or a result as big as the largest job.
TIMEOUT_SECONDS = 120.0


class RemoteError(Exception):
    """What went wrong, in one line fit for a terminal."""


class Remote:
    """A roadlink server at `url`, asked with the bearer `key` (none when auth is disabled)."""

    def __init__(self, url: str, key: str | None) -> None:
        import httpx

        headers = {"Authorization": f"Bearer {key}"} if key else {}
        self.url = url.rstrip("/")
        self.http = httpx.Client(base_url=self.url, headers=headers, timeout=TIMEOUT_SECONDS)

    def __enter__(self) -> Remote:
        return self

    def __exit__(self, *_exc: object) -> None:
        self.http.close()

    def request(self, method: str, path: str, **kwargs: Any) -> httpx.Response:
        """The answer, when it is a success; otherwise `RemoteError`."""
        import httpx

        try:
            response = self.http.request(method, path, **kwargs)
        except httpx.TransportError as exc:
            raise RemoteError(f"cannot reach {self.url}: {exc or type(exc).__name__}") from None
        if response.is_error:
            raise RemoteError(problem_line(response))
        return response

    def json(self, method: str, path: str, **kwargs: Any) -> Any:
        return self.request(method, path, **kwargs).json()


def problem_line(response: httpx.Response) -> str:
    """An error answer in one line: the RFC 9457 problem's status, title and detail when the
    server sent one (it does for every error), else the status and the start of the body."""
    try:
        problem = response.json()
    except ValueError:
        problem = None
    if isinstance(problem, dict) and "detail" in problem:
        title = problem.get("title") or response.reason_phrase
        return f"{response.status_code} {title}: {_one_line(str(problem['detail']))}"
    body = _one_line(response.text)[:200]
    return f"{response.status_code} {response.reason_phrase}" + (f": {body}" if body else "")


def _one_line(text: str) -> str:
    return " ".join(text.split())
