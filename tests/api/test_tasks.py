"""Background tasks of an API process (`api/tasks.py`): a task runs while its context lasts and
is cancelled, and awaited, at its end."""

from __future__ import annotations

import asyncio

from roadlink.api.tasks import in_background


def test_the_work_runs_while_the_context_lasts_and_is_cancelled_at_its_end() -> None:
    events: list[str] = []

    async def work(started: asyncio.Event) -> None:
        events.append("started")
        started.set()
        try:
            await asyncio.Event().wait()  # forever, until cancelled
        except asyncio.CancelledError:
            events.append("cancelled")
            raise

    async def main() -> None:
        started = asyncio.Event()
        async with in_background(work(started)):
            await started.wait()
            events.append("inside")
        events.append("after")  # the task was cancelled and awaited before the context ended

    asyncio.run(main())
    assert events == ["started", "inside", "cancelled", "after"]


def test_work_that_ended_by_itself_ends_the_context_quietly() -> None:
    async def quick() -> None:
        return None

    async def main() -> None:
        async with in_background(quick()):
            await asyncio.sleep(0)
            await asyncio.sleep(0)

    asyncio.run(main())
