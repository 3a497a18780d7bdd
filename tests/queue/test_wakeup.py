"""Idle workers and waiting result requests are woken by the news of the queue: from another
process (SQLite's doorbell, PostgreSQL's NOTIFY) before their poll interval."""

from __future__ import annotations

import asyncio
import multiprocessing
import time
import uuid

from sqlalchemy.orm import Session, sessionmaker

from roadlink.db.drivers import driver_for
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.queue.transitions import FINISHED_CHANNEL, NOTIFY_CHANNEL
from roadlink.queue.wakeup import FinishedJobs, make_wakeup


def _notify_later(database_url: str, channel: str, payload: str) -> None:
    """In another process: a transaction that notifies `channel`, committed after a pause."""
    time.sleep(0.2)
    engine = make_engine(database_url)
    sessions: sessionmaker[Session] = make_session_factory(engine)
    with transaction(sessions) as session:
        driver_for(database_url).notify(session, channel, [payload])
    engine.dispose()


def _notifier(database_url: str, channel: str, payload: str) -> multiprocessing.process.BaseProcess:
    process = multiprocessing.get_context("spawn").Process(
        target=_notify_later, args=(database_url, channel, payload)
    )
    process.start()
    return process


def test_an_idle_worker_wakes_on_an_enqueue_in_another_process(database_url: str) -> None:
    wakeup = make_wakeup(database_url)
    try:
        wakeup.wait(0.0)  # PostgreSQL: the LISTEN connection opens at the first wait
        notifier = _notifier(database_url, NOTIFY_CHANNEL, "")
        started = time.monotonic()
        wakeup.wait(60.0)
        waited = time.monotonic() - started
        notifier.join(30)
        assert waited < 60.0
    finally:
        wakeup.close()


def test_finished_jobs_wake_the_requests_waiting_for_them(database_url: str) -> None:
    job = uuid.uuid4()

    async def wait_for_the_news() -> bool:
        finished = FinishedJobs(database_url)
        finished.start()
        try:
            event = finished.watch(job)
            other = finished.watch(uuid.uuid4())
            deadline = time.monotonic() + 30
            while driver_for(database_url).name == "postgresql" and not finished.listening:
                assert time.monotonic() < deadline, "the listener never connected"
                await asyncio.sleep(0.01)
            notifier = _notifier(database_url, FINISHED_CHANNEL, str(job))
            await asyncio.wait_for(event.wait(), 30.0)
            notifier.join(30)
            return other.is_set()
        finally:
            finished.close()

    assert asyncio.run(wait_for_the_news()) is False, "only the finished job's waiter wakes"
