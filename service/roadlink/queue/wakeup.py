"""How an idle worker learns that a job was enqueued, and how a result request learns that its
job finished: by listening on the queue's channels through the database's driver
(`roadlink.db.drivers`: PostgreSQL LISTEN, SQLite's in-process news and doorbell), and by
polling, which covers whatever a listener misses."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import time
import uuid
from typing import Protocol

from roadlink.db.drivers import Listener, driver_for
from roadlink.queue.transitions import FINISHED_CHANNEL, NOTIFY_CHANNEL

log = logging.getLogger(__name__)


class Wakeup(Protocol):
    def wait(self, timeout: float) -> list[str]:
        """Return when work may be waiting, or after `timeout` seconds at the latest; the news
        heard (job ids, '' for news without one), if any."""

    def pass_on(self, news: list[str]) -> None:
        """Hand news heard and not acted on to another idle worker (where one is woken at a
        time: SQLite's doorbell)."""

    def close(self) -> None:
        """Release what the wake-up holds (e.g. its connection)."""


class ListeningWakeup:
    """Woken by the news of an enqueue, else after the poll interval.

    If the listener fails (the database may be restarting), the worker polls, and the listener
    reconnects at the next wait."""

    def __init__(self, listener: Listener) -> None:
        self._listener = listener

    def wait(self, timeout: float) -> list[str]:
        try:
            return self._listener.wait(timeout) or []
        except Exception as exc:
            log.warning("LISTEN connection failed (%s); polling instead", exc)
            time.sleep(timeout)
            return []

    def pass_on(self, news: list[str]) -> None:
        self._listener.pass_on(news)

    def close(self) -> None:
        self._listener.close()


def make_wakeup(database_url: str) -> Wakeup:
    """An idle worker's wake-up on this database: one idle worker is enough for a job."""
    return ListeningWakeup(driver_for(database_url).listen(NOTIFY_CHANNEL, one_of_many=True))


class FinishedJobs:
    """Wakes `?wait=` result requests when their job finishes.

    One thread per API process listens on the finished-jobs channel and wakes the requests
    waiting for the jobs it hears of. On PostgreSQL every finish is heard while the listener is
    connected; on SQLite a ring from another process may be lost, so requests poll as well
    (`listening` says whether notifications can be relied on).
    """

    RECONNECT_SECONDS = 1.0
    # How long the listening thread waits at a time: all it bounds is how long close() waits for
    # the thread (an app's shutdown, and every test's that starts one); a finish wakes it at once.
    CLOSE_WITHIN_SECONDS = 0.05

    def __init__(self, database_url: str) -> None:
        self._driver = driver_for(database_url)
        self._waiters: dict[str, set[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._thread: threading.Thread | None = None
        self._listener: Listener | None = None

    @property
    def listening(self) -> bool:
        """True when every finish will be heard (PostgreSQL, listener connected)."""
        return self._listener is not None and self._listener.hears_everything

    @property
    def rung(self) -> bool:
        """True when a finish in any process reaches this one, though one may be lost (SQLite's
        doorbell), or is sure to (`listening`)."""
        return self._listener is not None and self._listener.hears_others

    def start(self) -> None:
        """Start listening."""
        if self._thread is not None:
            return
        self._listener = self._driver.listen(FINISHED_CHANNEL)
        self._thread = threading.Thread(
            target=self._hear, args=(self._listener,), name="roadlink-finished-jobs", daemon=True
        )
        self._thread.start()

    def close(self) -> None:
        """Stop listening and forget every waiter."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._listener is not None:
            self._listener.close()
            self._listener = None

    def watch(self, job_id: uuid.UUID) -> asyncio.Event:
        """An event set when the job finishes; register before reading the job's state, so that
        a finish between the read and the wait is not missed. Give it back with `unwatch`."""
        event = asyncio.Event()
        with self._lock:
            self._waiters.setdefault(str(job_id), set()).add((asyncio.get_running_loop(), event))
        return event

    def unwatch(self, job_id: uuid.UUID, event: asyncio.Event) -> None:
        """Stop waking `event` for this job."""
        key = str(job_id)
        with self._lock:
            waiters = self._waiters.get(key, set())
            waiters = {w for w in waiters if w[1] is not event}
            if waiters:
                self._waiters[key] = waiters
            else:
                self._waiters.pop(key, None)

    def _wake(self, job_ids: list[str]) -> None:
        with self._lock:
            woken = [w for job_id in job_ids for w in self._waiters.get(job_id, ())]
        for loop, event in woken:
            with contextlib.suppress(RuntimeError):  # that request's loop has closed
                loop.call_soon_threadsafe(event.set)

    def _hear(self, listener: Listener) -> None:
        while not self._closing.is_set():
            try:
                job_ids = listener.wait(self.CLOSE_WITHIN_SECONDS)
            except Exception as exc:  # the database may be restarting: requests poll meanwhile
                log.warning("LISTEN for finished jobs failed (%s); retrying", exc)
                self._closing.wait(self.RECONNECT_SECONDS)
                continue
            if job_ids:
                self._wake(job_ids)
