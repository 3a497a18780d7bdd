"""SQLite, the embedded default: one host, writers serialised by the database file's lock.

Notifications: a transaction's news is delivered after its commit to the listeners of this
process, and rung on the database file's doorbell (`doorbell`) for the other processes. A ring
may be lost, so listeners are never sure to hear everything: their users poll as well.
"""

from __future__ import annotations

import os
import sqlite3
import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from functools import partial
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, event, make_url, update
from sqlalchemy.engine import ExceptionContext
from sqlalchemy.orm import Session

from roadlink.db.drivers import doorbell
from roadlink.db.drivers.backup_advice import BackupAdvice
from roadlink.db.models import utcnow

BUSY_TIMEOUT_SECONDS = 30.0
SYNCHRONOUS = ("full", "normal")

# SQLite errors after which a connection stays broken even once the cause is gone: a file opened
# while its directory was read-only stays read-only, a failed WAL or lock file stays failed.
_STUCK_ERRORS = (
    "readonly database",
    "disk i/o error",
    "unable to open database file",
    "database or disk is full",
)

_AFTER_COMMIT = "roadlink_after_commit"


class SqliteDriver:
    """SQLite: WAL, commits synced as ROADLINK_SQLITE_SYNCHRONOUS says, enforced foreign keys;
    this host's clock; claims need no row lock (writers are serialised); news after commit, in
    process and by doorbell."""

    name = "sqlite"

    def __init__(self, database_url: str) -> None:
        self._database_url = database_url

    def make_engine(self, database_url: str, *, sqlite_synchronous: str, **kwargs: Any) -> Engine:
        if sqlite_synchronous not in SYNCHRONOUS:
            raise ValueError(f"sqlite_synchronous must be one of {SYNCHRONOUS}")
        engine = create_engine(
            database_url,
            # API threads and the worker's heartbeat thread share the pool.
            connect_args={"check_same_thread": False, "timeout": BUSY_TIMEOUT_SECONDS},
            **kwargs,
        )
        event.listen(engine, "connect", partial(_configure_connection, sqlite_synchronous))
        event.listen(engine, "handle_error", _drop_connections_that_cannot_write)
        return engine

    def backup(self, path: str) -> None:
        # VACUUM INTO copies in one read transaction: a consistent snapshot that, in WAL mode,
        # does not hold up writers; it refuses a target that exists and is not empty.
        source = make_url(self._database_url).database
        if not source or source == ":memory:":
            raise BackupAdvice("an in-memory database has nothing on disk to copy")
        if os.path.exists(path):
            raise FileExistsError(f"{path} exists; roadlink backup never overwrites a file")
        connection = sqlite3.connect(source, timeout=BUSY_TIMEOUT_SECONDS)
        try:
            connection.execute("VACUUM INTO ?", (path,))
        finally:
            connection.close()

    def clock(self) -> Any:
        # Embedded, so every process using the file shares this host's clock.
        return utcnow()

    def lock_for_claim(self, query: Any) -> Any:
        return query

    def lock_row(
        self, session: Session, key: Any, value: Any, *, other_column: Any, exclusive: bool
    ) -> bool:
        # SQLite locks the database, not rows, and only to write: rewriting a column of the row
        # (not a key, whose rewrite would check every referencing row) takes the write lock,
        # which serialises this transaction with every other writer, shared or not.
        statement = update(key.table).where(key == value).values({other_column: other_column})
        return bool(session.execute(statement).rowcount)  # type: ignore[attr-defined]

    def notify(self, session: Session, channel: str, payloads: Sequence[str]) -> None:
        database_url = self._database_url

        def deliver() -> None:
            _local_listeners.deliver(channel, payloads)
            doorbell.ring(database_url, channel, "\n".join(payloads).encode())

        after_commit(session, deliver)

    def listen(self, channel: str, *, one_of_many: bool = False) -> SqliteListener:
        return SqliteListener(self._database_url, channel, one_of_many=one_of_many)

    # SQLite cannot ALTER most things; Alembic's batch mode recreates the table instead.
    rebuilds_tables = True

    @contextmanager
    def migrating(self, connection: Connection) -> Iterator[None]:
        """Foreign keys off while migrating, checked after: batch mode copies a table and drops
        the original, and with foreign keys enforced dropping `batch` would delete its
        detections (ON DELETE CASCADE). Set outside a transaction, where SQLite honours it."""
        connection.exec_driver_sql("PRAGMA foreign_keys=OFF")
        connection.commit()
        yield
        broken = connection.exec_driver_sql("PRAGMA foreign_key_check").all()
        connection.commit()
        if broken:
            raise RuntimeError(f"the migration left rows that break foreign keys: {broken[:5]}")

    def lock_migrations(self, connection: Connection) -> None:
        pass  # the database file's write lock serialises migrations already


def _configure_connection(synchronous: str, dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    # WAL lets the API read while a worker writes. synchronous=FULL syncs the WAL at every
    # commit (durable against power loss); NORMAL syncs it at checkpoints only: a commit
    # survives a crash of the process, and a power loss may lose the last ones, never half of
    # one (ROADLINK_SQLITE_SYNCHRONOUS, docs/deploy.md).
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute(f"PRAGMA synchronous={synchronous.upper()}")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={int(BUSY_TIMEOUT_SECONDS * 1000)}")
    cursor.close()


def _drop_connections_that_cannot_write(context: ExceptionContext) -> None:
    """Treat such an error as a lost connection: SQLAlchemy then discards the pool's connections
    and opens new ones, so the service recovers by itself once the storage does. (PostgreSQL's
    lost connections are recognised by SQLAlchemy already.)"""
    text = str(context.original_exception).lower()
    if any(message in text for message in _STUCK_ERRORS):
        context.is_disconnect = True


def after_commit(session: Session, action: Callable[[], None]) -> None:
    """Run `action` once the session's transaction commits (never if it rolls back).

    The hooks are attached to this session only, the first time it has such work: sessions
    that never notify on SQLite carry none."""
    if not event.contains(session, "after_commit", _run_after_commit):
        event.listen(session, "after_commit", _run_after_commit)
        event.listen(session, "after_soft_rollback", _drop_after_rollback)
    session.info.setdefault(_AFTER_COMMIT, []).append(action)


def _run_after_commit(session: Session) -> None:
    for action in session.info.pop(_AFTER_COMMIT, []):
        action()


def _drop_after_rollback(session: Session, _previous_transaction: Any) -> None:
    session.info.pop(_AFTER_COMMIT, None)


class SqliteListener:
    """Hears the news of this process at its commit, and of other processes by the doorbell."""

    hears_everything = False  # a ring may be lost

    @property
    def hears_others(self) -> bool:
        """Whether other processes' news rings it (an in-memory database has no doorbell)."""
        return self._doorbell is not None

    def __init__(self, database_url: str, channel: str, *, one_of_many: bool = False) -> None:
        self._database_url = database_url
        self._channel = channel
        self._heard = threading.Event()
        self._payloads: list[str] = []
        self._lock = threading.Lock()
        self._doorbell = doorbell.listen(database_url, channel, one_of_many=one_of_many)
        _local_listeners.add(channel, self)

    def hear(self, payloads: Sequence[str]) -> None:
        """Take news from a commit in this process (called in the committing thread)."""
        with self._lock:
            self._payloads.extend(payloads)
            self._heard.set()

    def wait(self, timeout: float) -> list[str] | None:
        rings: list[bytes] = []
        if not self._heard.is_set():
            if self._doorbell is None:  # in-memory databases have no doorbell
                self._heard.wait(timeout)
            else:
                # News of this process rings this socket too, so one wait covers both.
                rings = self._doorbell.wait(timeout)
        if self._doorbell is not None:
            rings += self._doorbell.drain()
        heard = self._take()
        if heard is None and not rings:
            return None
        rung = [p for m in rings for p in m.decode(errors="replace").split("\n")]
        # News from this process arrives twice (heard, and rung): once is enough.
        return [p for p in dict.fromkeys([*(heard or []), *rung]) if p]

    def _take(self) -> list[str] | None:
        with self._lock:
            if not self._heard.is_set():
                return None
            payloads, self._payloads = self._payloads, []
            self._heard.clear()
            return payloads

    def pass_on(self, payloads: Sequence[str]) -> None:
        doorbell.ring(self._database_url, self._channel, "\n".join(payloads).encode())

    def close(self) -> None:
        _local_listeners.remove(self._channel, self)
        if self._doorbell is not None:
            self._doorbell.close()
            self._doorbell = None


class _LocalListeners:
    """The listeners of this process, per channel, told of commits made in this process."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._by_channel: dict[str, set[SqliteListener]] = {}

    def add(self, channel: str, listener: SqliteListener) -> None:
        with self._lock:
            self._by_channel.setdefault(channel, set()).add(listener)

    def remove(self, channel: str, listener: SqliteListener) -> None:
        with self._lock:
            self._by_channel.get(channel, set()).discard(listener)

    def deliver(self, channel: str, payloads: Sequence[str]) -> None:
        with self._lock:
            listeners = list(self._by_channel.get(channel, ()))
        for listener in listeners:
            listener.hear(payloads)


_local_listeners = _LocalListeners()
