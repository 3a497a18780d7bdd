"""How an idle worker learns that a job was enqueued: PostgreSQL LISTEN, or polling."""

from __future__ import annotations

import contextlib
import logging
from typing import Any, Protocol

from sqlalchemy import make_url

from service.queue.jobs import NOTIFY_CHANNEL, local_enqueue_signal

log = logging.getLogger(__name__)


class Wakeup(Protocol):
    def wait(self, timeout: float) -> None:
        """Return when work may be waiting, or after `timeout` seconds at the latest."""

    def close(self) -> None:
        """Release what the wake-up holds (e.g. its connection)."""


class PollingWakeup:
    """SQLite: woken at once by an enqueue in this process, else after the poll interval."""

    def wait(self, timeout: float) -> None:
        if local_enqueue_signal.wait(timeout):
            local_enqueue_signal.clear()

    def close(self) -> None:
        return None


class PostgresWakeup:
    """PostgreSQL: LISTEN on the queue channel on a connection of its own.

    A NOTIFY is sent in the enqueueing transaction, so it arrives the moment the job commits.
    If the listening connection breaks, the worker still polls, and the connection is reopened.
    """

    def __init__(self, database_url: str) -> None:
        url = make_url(database_url).set(drivername="postgresql")
        self._conninfo = url.render_as_string(hide_password=False)
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
    return PollingWakeup()
