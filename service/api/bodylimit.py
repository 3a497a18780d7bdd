"""Refusing oversized request bodies (413) before they are read into memory."""

from __future__ import annotations

from starlette.exceptions import HTTPException
from starlette.types import ASGIApp, Message, Receive, Scope, Send


class BodyTooLarge(HTTPException):
    """The body exceeds the limit; answered as 413 naming the limit.

    An HTTPException, because FastAPI re-raises those from its own body reading (and turns any
    other exception there into a 400), so a chunked body that outgrows the limit while FastAPI
    reads it is still a 413.
    """

    def __init__(self, limit: int) -> None:
        super().__init__(413, f"the request body is larger than the limit of {limit} bytes")
        self.limit = limit

    def __str__(self) -> str:
        return str(self.detail)


class BodyLimitMiddleware:
    """Rejects a body whose Content-Length exceeds `limit`, and stops a chunked body that
    grows past it while the handler reads it."""

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", ()):
            if name == b"content-length" and value.isdigit() and int(value) > self.limit:
                await self._refuse(scope, send)
                return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    raise BodyTooLarge(self.limit)
            return message

        await self.app(scope, limited_receive, send)

    async def _refuse(self, scope: Scope, send: Send) -> None:
        from service.api.errors import PROBLEM_MEDIA_TYPE, ProblemDetail

        body = (
            ProblemDetail(
                title="Content Too Large",
                status=413,
                detail=f"the request body is larger than the limit of {self.limit} bytes "
                "(ROADLINK_MAX_BODY_BYTES); split the batch into smaller ones",
                instance=scope.get("path"),
            )
            .model_dump_json()
            .encode()
        )
        await send(
            {
                "type": "http.response.start",
                "status": 413,
                "headers": [
                    (b"content-type", PROBLEM_MEDIA_TYPE.encode()),
                    (b"content-length", str(len(body)).encode()),
                    (b"connection", b"close"),
                ],
            }
        )
        await send({"type": "http.response.body", "body": body})
