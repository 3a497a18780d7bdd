"""The task of each API process that forgets expired Idempotency-Keys (after
ROADLINK_IDEMPOTENCY_HOURS). The rule the keys serve is `services/idempotency.py`."""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import AsyncIterator

from fastapi import FastAPI
from starlette.concurrency import run_in_threadpool

from roadlink.api.tasks import in_background
from roadlink.services.idempotency import forget_expired_keys

log = logging.getLogger("roadlink")

# How often an API process forgets expired keys; keys live between the retention and this more.
FORGET_EVERY_SECONDS = 3600.0


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

    async with in_background(loop()):
        yield
