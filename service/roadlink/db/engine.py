"""Engine and session factory for SQLite (embedded default) and PostgreSQL."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import Engine, create_engine, event, text
from sqlalchemy.engine import ExceptionContext
from sqlalchemy.orm import Session, sessionmaker

SQLITE_BUSY_TIMEOUT_SECONDS = 30.0


def make_engine(database_url: str, **kwargs: Any) -> Engine:
    """An engine for `database_url`; SQLite gets WAL, durable commits and enforced foreign keys."""
    if database_url.startswith("sqlite"):
        engine = create_engine(
            database_url,
            # API threads and the worker's heartbeat thread share the pool.
            connect_args={"check_same_thread": False, "timeout": SQLITE_BUSY_TIMEOUT_SECONDS},
            **kwargs,
        )
        event.listen(engine, "connect", _configure_sqlite)
    else:
        engine = create_engine(database_url, pool_pre_ping=True, **kwargs)
    event.listen(engine, "handle_error", _drop_connections_that_cannot_write)
    return engine


# SQLite errors after which a connection stays broken even once the cause is gone: a file opened
# while its directory was read-only stays read-only, a failed WAL or lock file stays failed.
_STUCK_SQLITE_ERRORS = (
    "readonly database",
    "disk i/o error",
    "unable to open database file",
    "database or disk is full",
)


def _drop_connections_that_cannot_write(context: ExceptionContext) -> None:
    """Treat such an error as a lost connection: SQLAlchemy then discards the pool's connections
    and opens new ones, so the service recovers by itself once the storage does. (PostgreSQL's
    lost connections are recognised by SQLAlchemy already.)"""
    if context.engine is not None and context.engine.dialect.name != "sqlite":
        return
    text = str(context.original_exception).lower()
    if any(message in text for message in _STUCK_SQLITE_ERRORS):
        context.is_disconnect = True


def check_writable(engine: Engine) -> None:
    """Raise unless the database takes a write now: a no-op update of the migration table,
    rolled back (so nothing changes, and a read-only file or server says so)."""
    with engine.connect() as connection, connection.begin() as transaction:
        connection.execute(text("UPDATE alembic_version SET version_num = version_num"))
        transaction.rollback()


def _configure_sqlite(dbapi_connection: Any, _record: Any) -> None:
    cursor = dbapi_connection.cursor()
    # WAL lets the API read while a worker writes; synchronous=FULL makes every commit durable
    # (the default NORMAL in WAL mode may lose the last commits on power loss).
    cursor.execute("PRAGMA journal_mode=WAL")
    cursor.execute("PRAGMA synchronous=FULL")
    cursor.execute("PRAGMA foreign_keys=ON")
    cursor.execute(f"PRAGMA busy_timeout={int(SQLITE_BUSY_TIMEOUT_SECONDS * 1000)}")
    cursor.close()


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Sessions that keep loaded objects usable after commit (responses are built after it)."""
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def transaction(factory: sessionmaker[Session]) -> Iterator[Session]:
    """A session whose work commits on success and rolls back on any exception."""
    with factory() as session, session.begin():
        yield session
