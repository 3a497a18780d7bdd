"""PostgreSQL, for scaling out: workers and API replicas on several hosts.

Notifications are NOTIFY, sent in the transaction that makes the news true (so delivered at its
commit, never on rollback), heard by LISTEN on a connection of the listener's own.
"""

from __future__ import annotations

import contextlib
import shlex
from collections.abc import Iterator, Sequence
from typing import Any

from sqlalchemy import Connection, Engine, create_engine, func, make_url, select, text
from sqlalchemy.orm import Session

from roadlink.db.drivers.backup_advice import BackupAdvice

# Any constant shared by every roadlink process: the advisory lock serialising migrations.
MIGRATION_LOCK_KEY = 0x726F61646C696E6B  # "roadlink"


class PostgresDriver:
    """PostgreSQL: the database's clock; claims skip rows other workers have locked; NOTIFY."""

    name = "postgresql"

    def __init__(self, database_url: str) -> None:
        self._url = database_url
        self._conninfo = libpq_conninfo(database_url)

    def make_engine(self, database_url: str, *, sqlite_synchronous: str, **kwargs: Any) -> Engine:
        # Every commit waits for the server's WAL flush (synchronous_commit as the server has it).
        return create_engine(database_url, pool_pre_ping=True, **kwargs)

    def clock(self) -> Any:
        # One clock for every host: the hosts' own clocks drift apart.
        return func.now()

    def backup(self, path: str) -> None:
        # pg_dump takes a consistent snapshot while the service runs, and restores with
        # pg_restore to any server version at least as new; roadlink cannot do better.
        url = make_url(libpq_conninfo(self._url)).render_as_string(hide_password=True)
        raise BackupAdvice(
            "roadlink does not copy a PostgreSQL database; pg_dump does, consistently and while "
            "the service runs:\n"
            f"  pg_dump --format=custom --file {shlex.quote(path)} {shlex.quote(url)}\n"
            "(the password from PGPASSWORD or ~/.pgpass). Restore it into an empty database "
            "with\n"
            f"  pg_restore --dbname <url of the new database> {shlex.quote(path)}"
        )

    def lock_for_claim(self, query: Any) -> Any:
        # Concurrent workers each take a different job without waiting for each other.
        return query.with_for_update(skip_locked=True)

    def lock_row(
        self, session: Session, key: Any, value: Any, *, other_column: Any, exclusive: bool
    ) -> bool:
        # Exclusive is FOR UPDATE: it also waits for (and holds up) the KEY SHARE locks that
        # inserting a row referencing this one takes.
        query = select(key).where(key == value).with_for_update(read=not exclusive)
        return session.execute(query).first() is not None

    def notify(self, session: Session, channel: str, payloads: Sequence[str]) -> None:
        # One notification per payload: a payload is limited to 8000 bytes.
        for payload in payloads:
            session.execute(
                text("SELECT pg_notify(:channel, :payload)"),
                {"channel": channel, "payload": payload},
            )

    def listen(self, channel: str, *, one_of_many: bool = False) -> PostgresListener:
        return PostgresListener(self._conninfo, channel)

    rebuilds_tables = False

    @contextlib.contextmanager
    def migrating(self, connection: Connection) -> Iterator[None]:
        yield

    def lock_migrations(self, connection: Connection) -> None:
        # Several API replicas may start at once: one migrates, the others wait.
        connection.execute(text("SELECT pg_advisory_xact_lock(:key)"), {"key": MIGRATION_LOCK_KEY})


def libpq_conninfo(database_url: str) -> str:
    """The libpq URL psycopg connects with, from a SQLAlchemy URL."""
    url = make_url(database_url).set(drivername="postgresql")
    return url.render_as_string(hide_password=False)


class PostgresListener:
    """LISTEN on a connection of its own, opened at the first wait and reopened after a failure."""

    def __init__(self, conninfo: str, channel: str) -> None:
        self._conninfo = conninfo
        self._channel = channel
        self._connection: Any = None

    @property
    def hears_everything(self) -> bool:
        return self._connection is not None and not self._connection.closed

    @property
    def hears_others(self) -> bool:
        return self.hears_everything

    def wait(self, timeout: float) -> list[str] | None:
        try:
            connection = self._connect()
            payloads = [n.payload for n in connection.notifies(timeout=timeout, stop_after=1)]
        except Exception:
            self.close()
            raise
        return payloads or None

    def _connect(self) -> Any:
        import psycopg  # only needed on PostgreSQL

        if self._connection is None or self._connection.closed:
            connection = psycopg.connect(self._conninfo, autocommit=True)
            try:
                connection.execute(f"LISTEN {self._channel}")
            except Exception:
                connection.close()
                raise
            self._connection = connection  # listening from now on
        return self._connection

    def pass_on(self, payloads: Sequence[str]) -> None:
        pass  # every listener heard the NOTIFY

    def close(self) -> None:
        if self._connection is not None:
            with contextlib.suppress(Exception):
                self._connection.close()
            self._connection = None
