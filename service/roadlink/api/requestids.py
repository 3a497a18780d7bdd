"""X-Request-ID: taken from the client when it is fit to log (else made up), echoed on every
response, errors included, and carried by every log line of the request (roadlink.logs).

The outermost layer of the app, so that it wraps everything that may answer or log, the problem
for an unexpected exception and uvicorn's access log line (written when the response starts)
included. The ids of the deployment, batch or job a path names are set here too, from the path
itself: routing happens further in, in tasks whose context does not reach back out here.
"""

from __future__ import annotations

import re

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from roadlink.logs import accepted_request_id, log_context

HEADER = "X-Request-ID"
_HEADER_KEY = HEADER.lower().encode("latin-1")

_UUID = r"[0-9a-fA-F-]{32,36}"
_PATH_IDS = (
    ("deployment_id", re.compile(rf"^/v1/deployments/({_UUID})(?:/|$)")),
    ("batch_id", re.compile(rf"^/v1/batches/({_UUID})(?:/|$)")),
    ("job_id", re.compile(rf"^/(?:v1/)?jobs/({_UUID})(?:/|$)")),
)


class RequestIdMiddleware:
    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given = None
        for name, value in scope.get("headers", ()):
            if name == _HEADER_KEY:
                given = value.decode("latin-1")
                break
        request_id = accepted_request_id(given)
        path = scope.get("path", "")
        ids = {name: m.group(1) for name, pattern in _PATH_IDS if (m := pattern.match(path))}
        encoded = request_id.encode("latin-1")

        async def send_with_id(message: Message) -> None:
            if message["type"] == "http.response.start":
                headers = [(k, v) for k, v in message.get("headers", ()) if k != _HEADER_KEY]
                message = {**message, "headers": [*headers, (_HEADER_KEY, encoded)]}
            await send(message)

        with log_context(request_id=request_id, **ids):
            await self.app(scope, receive, send_with_id)
