"""How an idle worker learns that a job was enqueued, and how a result request learns that its
job finished: PostgreSQL LISTEN, SQLite's doorbell (`roadlink.queue.doorbell`), in-process
signals, or polling."""

from __future__ import annotations

import asyncio
import contextlib
import logging
import threading
import uuid
from typing import Any, Protocol

from sqlalchemy import make_url

from roadlink.queue import doorbell
from roadlink.queue.transitions import (
    FINISHED_CHANNEL,
    NOTIFY_CHANNEL,
    local_enqueue_signal,
    subscribe_local_finishes,
    unsubscribe_local_finishes,
)

log = logging.getLogger(__name__)


class Wakeup(Protocol):
    def wait(self, timeout: float) -> None:
        """Return when work may be waiting, or after `timeout` seconds at the latest."""

    def close(self) -> None:
        """Release what the wake-up holds (e.g. its connection)."""


class PollingWakeup:
    """SQLite: woken at once by an enqueue in this process or, through the database file's
    doorbell, in another process; else after the poll interval."""

    def __init__(self, database_url: str = "") -> None:
        self._doorbell = doorbell.listen(database_url, doorbell.QUEUED) if database_url else None

    def wait(self, timeout: float) -> None:
        if self._doorbell is None:
            if local_enqueue_signal.wait(timeout):
                local_enqueue_signal.clear()
            return
        # An enqueue in this process rings the doorbell too; the event covers one that
        # happened before this wait began.
        if local_enqueue_signal.is_set():
            local_enqueue_signal.clear()
            self._doorbell.drain()
            return
        if self._doorbell.wait(timeout):
            local_enqueue_signal.clear()

    def close(self) -> None:
        if self._doorbell is not None:
            self._doorbell.close()
            self._doorbell = None


class PostgresWakeup:
    """PostgreSQL: LISTEN on the queue channel on a connection of its own.

    A NOTIFY is sent in the enqueueing transaction, so it arrives the moment the job commits.
    If the listening connection breaks, the worker still polls, and the connection is reopened.
    """

    def __init__(self, database_url: str) -> None:
        self._conninfo = libpq_conninfo(database_url)
        self._connection: Any = None

    def _listen(self) -> Any:
        import psycopg  # only needed on PostgreSQL

        if self._connection is None or self._connection.closed:
            self._connection = psycopg.connect(self._conninfo, autocommit=True)
            self._connection.execute(f"LISTEN {NOTIFY_CHANNEL}")
        return self._connection

    def wait(self, timeout: float) -> None:
        try:
            connection = self._listen()
            for _ in connection.notifies(timeout=timeout, stop_after=1):
                break
        except Exception as exc:  # the database may be restarting: poll until it is back
            log.warning("LISTEN connection failed (%s); polling instead", exc)
            self.close()
            local_enqueue_signal.wait(timeout)

    def close(self) -> None:
        if self._connection is not None:
            with contextlib.suppress(Exception):
                self._connection.close()
            self._connection = None


def make_wakeup(database_url: str) -> Wakeup:
    """The wake-up suited to the database."""
    if database_url.startswith("postgresql"):
        return PostgresWakeup(database_url)
    return PollingWakeup(database_url)


def libpq_conninfo(database_url: str) -> str:
    """The libpq URL psycopg connects with, from a SQLAlchemy URL."""
    url = make_url(database_url).set(drivername="postgresql")
    return url.render_as_string(hide_password=False)


class FinishedJobs:
    """Wakes `?wait=` result requests when their job finishes.

    On PostgreSQL one thread per API process LISTENs on the finished-jobs channel (the NOTIFY is
    sent in the finishing transaction) and wakes the requests waiting for that job. On SQLite it
    hears of jobs finished by workers in this process, and of those finished in other processes
    through the database file's doorbell (a thread reads it); a ring may be lost, so requests
    poll as well (`listening` says whether notifications can be relied on).
    """

    RECONNECT_SECONDS = 1.0

    def __init__(self, database_url: str) -> None:
        self._postgres = database_url.startswith("postgresql")
        self._database_url = database_url
        self._conninfo = libpq_conninfo(database_url) if self._postgres else ""
        self._waiters: dict[str, set[tuple[asyncio.AbstractEventLoop, asyncio.Event]]] = {}
        self._lock = threading.Lock()
        self._closing = threading.Event()
        self._connected = threading.Event()
        self._thread: threading.Thread | None = None
        self._doorbell: doorbell.Listener | None = None
        if not self._postgres:
            subscribe_local_finishes(self._wake)

    @property
    def listening(self) -> bool:
        """True when every finish will be heard (PostgreSQL, listener connected)."""
        return self._connected.is_set()

    def start(self) -> None:
        """Start listening: on PostgreSQL's channel, or on the SQLite file's doorbell."""
        if self._thread is not None:
            return
        if self._postgres:
            self._thread = threading.Thread(
                target=self._listen, name="roadlink-finished-jobs", daemon=True
            )
        else:
            self._doorbell = doorbell.listen(self._database_url, doorbell.FINISHED)
            if self._doorbell is None:
                return
            self._thread = threading.Thread(
                target=self._hear_doorbell,
                args=(self._doorbell,),
                name="roadlink-finished-jobs",
                daemon=True,
            )
        self._thread.start()

    def close(self) -> None:
        """Stop listening and forget every waiter."""
        self._closing.set()
        if self._thread is not None:
            self._thread.join(5.0)
            self._thread = None
        if self._doorbell is not None:
            self._doorbell.close()
            self._doorbell = None
        if not self._postgres:
            unsubscribe_local_finishes(self._wake)

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

    def _hear_doorbell(self, listener: doorbell.Listener) -> None:
        while not self._closing.is_set():
            # The timeout only bounds how long close() waits for this thread.
            messages = listener.wait(0.5)
            job_ids = [j for m in messages for j in m.decode(errors="replace").split("\n") if j]
            if job_ids:
                self._wake(job_ids)

    def _listen(self) -> None:
        import psycopg  # only needed on PostgreSQL

        while not self._closing.is_set():
            try:
                with psycopg.connect(self._conninfo, autocommit=True) as connection:
                    connection.execute(f"LISTEN {FINISHED_CHANNEL}")
                    self._connected.set()
                    while not self._closing.is_set():
                        # The timeout only bounds how long close() waits for this thread.
                        for notify in connection.notifies(timeout=0.5):
                            self._wake([notify.payload])
            except Exception as exc:  # the database may be restarting: requests poll meanwhile
                self._connected.clear()
                log.warning("LISTEN for finished jobs failed (%s); retrying", exc)
                self._closing.wait(self.RECONNECT_SECONDS)
        self._connected.clear()
