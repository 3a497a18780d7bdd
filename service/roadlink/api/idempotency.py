"""The `Idempotency-Key` header of POST /v1/jobs, the digest of a request, and the task of each
API process that forgets expired keys. The rule itself (a retry gets what the first request
created, `Idempotent-Replayed: true`; another body with the same key is a 422) is
`services/idempotency.py`.
"""

from __future__ import annotations

import asyncio
import contextlib
import hashlib
import logging
from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import FastAPI, Header
from pydantic import BaseModel
from starlette.concurrency import run_in_threadpool

from roadlink.services.idempotency import forget_expired_keys

log = logging.getLogger("roadlink")

# How often an API process forgets expired keys; keys live between the retention and this more.
FORGET_EVERY_SECONDS = 3600.0

IdempotencyKeyHeader = Annotated[
    str | None,
    Header(
        alias="Idempotency-Key",
        min_length=1,
        max_length=200,
        description="Makes retries safe: a repeated request with the same key (from the same API "
        "key) returns the job the first one created; the same key with a different body is an "
        "error (422). Keys are remembered for at least 24 hours.",
    ),
]


def request_sha256(body: BaseModel) -> str:
    """A digest of the request as parsed (so whitespace or key order do not make it differ)."""
    return hashlib.sha256(body.model_dump_json().encode()).hexdigest()


@contextlib.asynccontextmanager
async def forgetting_expired_keys(app: FastAPI) -> AsyncIterator[None]:
    """A lifespan: while the app runs, forget expired Idempotency-Keys every hour."""

    async def loop() -> None:
        while True:
            try:
                forgotten = await run_in_threadpool(
                    forget_expired_keys, app.state.sessions, app.state.settings
                )
                if forgotten.batches or forgotten.jobs:
                    log.info(
                        "forgot the Idempotency-Keys of %d batch(es) and %d job(s)",
                        forgotten.batches,
                        forgotten.jobs,
                    )
            except Exception:  # a busy or unmigrated database: try again next round
                log.warning("could not forget expired Idempotency-Keys", exc_info=True)
            await asyncio.sleep(FORGET_EVERY_SECONDS)

    task = asyncio.create_task(loop())
    try:
        yield
    finally:
        task.cancel()
        with contextlib.suppress(asyncio.CancelledError):
            await task
