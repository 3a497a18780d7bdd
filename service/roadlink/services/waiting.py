"""The long-poll wait of `GET /v1/jobs/{id}/result?wait=`: until the job finishes, the wait
runs out or the client goes away."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Awaitable, Callable
from contextlib import suppress

from roadlink.db.models import Job
from roadlink.queue.wakeup import FinishedJobs
from roadlink.services.problems import ServiceProblem

# A waiting result request is woken by the job's finish notification (PostgreSQL, a worker in
# this process, or SQLite's doorbell from a worker in another); it also re-reads the job, often
# at first and backing off to the maximum, which is all it has when no notification can reach it
# (SQLite without a doorbell).
WAIT_FIRST_POLL_SECONDS = 0.02
WAIT_MAX_POLL_SECONDS = 0.25
# Rung by the doorbell, re-reading covers only a ring that was lost: every 250 ms from the start,
# as an idle worker polls. (At 20 ms, the second read of a paper-size job's request came as the
# job finished, a third of the time: a read for nothing on the API's cores at that moment.)
WAIT_RUNG_POLL_SECONDS = 0.25
# While notifications are heard, re-reading only covers one lost in a reconnection.
WAIT_LISTENING_POLL_SECONDS = 2.0


async def wait_for_job(
    job_id: uuid.UUID,
    *,
    wait: float,
    max_wait: float,
    read_job: Callable[[], Awaitable[Job | None]],
    finished_jobs: FinishedJobs | None,
    client_gone: Callable[[], Awaitable[bool]],
) -> Job:
    """The job once it has finished, or as it stands after `wait` seconds (at most `max_wait`);
    404 when there is no such job, 408 when the client went away meanwhile. `read_job` reads
    the job anew each time (the caller runs the blocking read off the event loop)."""
    deadline = time.monotonic() + min(wait, max_wait)
    # Watched before the first read, so that a finish between the read and the wait is heard.
    finished = None if finished_jobs is None or wait <= 0 else finished_jobs.watch(job_id)
    try:
        rung = finished_jobs is not None and finished_jobs.rung
        pause = WAIT_RUNG_POLL_SECONDS if rung else WAIT_FIRST_POLL_SECONDS
        while True:
            job = await read_job()
            if job is None:
                raise ServiceProblem(404, f"there is no job {job_id}")
            if job.state.finished or time.monotonic() >= deadline:
                return job
            if await client_gone():
                raise ServiceProblem(408, "the client went away while waiting")
            timeout = min(pause, max(deadline - time.monotonic(), 0.0))
            if finished is None:
                await asyncio.sleep(timeout)
            else:
                with suppress(TimeoutError):
                    await asyncio.wait_for(finished.wait(), timeout)
                finished.clear()
            listening = finished_jobs is not None and finished_jobs.listening
            pause = min(
                pause * 2, WAIT_LISTENING_POLL_SECONDS if listening else WAIT_MAX_POLL_SECONDS
            )
    finally:
        if finished is not None and finished_jobs is not None:
            finished_jobs.unwatch(job_id, finished)
