"""Refusing oversized request bodies (413) before they are read into memory."""

from __future__ import annotations

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from roadlink.association.numbers import parse_unsigned


class BodyLimitMiddleware:
    """Rejects a body whose Content-Length exceeds `limit`, and stops a chunked body that
    grows past it while the handler reads it.

    A chunked body is answered 413 from inside `receive`, the moment it passes the limit; the
    app is then told the client has gone (`http.disconnect`), whatever it sends afterwards is
    dropped, and whatever it raises about the missing body is swallowed. Raising from `receive`
    instead would not work: Starlette's BaseHTTPMiddleware reads the body in a task group, which
    turns the exception into an ExceptionGroup and the answer into a 500.
    """

    def __init__(self, app: ASGIApp, limit: int) -> None:
        self.app = app
        self.limit = limit

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        for name, value in scope.get("headers", ()):
            declared = parse_unsigned(value, max_digits=19) if name == b"content-length" else None
            if declared is not None and declared > self.limit:
                await self._refuse(scope, send)
                return
        received = 0
        refused = False
        started = False

        async def limited_receive() -> Message:
            nonlocal received, refused
            if refused:
                return {"type": "http.disconnect"}
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.limit:
                    refused = True
                    if not started:
                        await self._refuse(scope, send)
                    return {"type": "http.disconnect"}
            return message

        async def guarded_send(message: Message) -> None:
            nonlocal started
            if refused:
                return  # the 413 has been sent; the app's own answer goes nowhere
            if message["type"] == "http.response.start":
                started = True
            await send(message)

        try:
            await self.app(scope, limited_receive, guarded_send)
        except Exception:
            if not refused:
                raise
            # The app failed on the body it never got whole; the client has its 413.

    async def _refuse(self, scope: Scope, send: Send) -> None:
        from roadlink.api.errors import PROBLEM_MEDIA_TYPE, ProblemDetail

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
