"""Engine and session factory for SQLite (embedded default) and PostgreSQL."""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

from sqlalchemy import Engine, text
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db.drivers import driver_for


def make_engine(database_url: str, **kwargs: Any) -> Engine:
    """An engine for `database_url`, set up by its database's driver (`roadlink.db.drivers`)."""
    return driver_for(database_url).make_engine(database_url, **kwargs)


def check_writable(engine: Engine) -> None:
    """Raise unless the database takes a write now: a no-op update of the migration table,
    rolled back (so nothing changes, and a read-only file or server says so)."""
    with engine.connect() as connection, connection.begin() as transaction:
        connection.execute(text("UPDATE alembic_version SET version_num = version_num"))
        transaction.rollback()


def make_session_factory(engine: Engine) -> sessionmaker[Session]:
    """Sessions that keep loaded objects usable after commit (responses are built after it)."""
    return sessionmaker(engine, expire_on_commit=False)


@contextmanager
def transaction(factory: sessionmaker[Session]) -> Iterator[Session]:
    """A session whose work commits on success and rolls back on any exception."""
    with factory() as session, session.begin():
        yield session
