"""The Idempotency-Key header, declared once for every route that takes it: its rules for the
key (a non-empty string of at most 200 characters), and the request it makes idempotent, with
its sender and digest (the rule itself: `roadlink.services.idempotency`)."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Header, Request
from starlette.concurrency import run_in_threadpool

from roadlink.api.auth import principal_of
from roadlink.services.idempotency import IdempotentRequest, request_digest


def media_type(request: Request) -> str:
    """The request's content type without its parameters, lower case ('' when none)."""
    return request.headers.get("content-type", "").split(";")[0].strip().lower()


async def idempotent_request(
    request: Request,
    idempotency_key: Annotated[
        str | None,
        Header(
            alias="Idempotency-Key",
            min_length=1,
            max_length=200,
            description="Makes retries safe: a repeated request with the same key (from the same "
            "API key, to the same endpoint) returns what the first one created; the same key "
            "with a different body is an error (422). Keys are remembered for at least 24 hours.",
        ),
    ] = None,
) -> IdempotentRequest | None:
    """The request as its Idempotency-Key scopes it, or None when it came without one."""
    if idempotency_key is None:
        return None
    body = await request.body()
    # Off the event loop: a batch's JSON may be megabytes to put in canonical form.
    digest = await run_in_threadpool(request_digest, media_type(request), body)
    return IdempotentRequest(key=idempotency_key, principal=principal_of(request).id, digest=digest)


IdempotencyDep = Annotated[IdempotentRequest | None, Depends(idempotent_request)]
