"""PostgreSQL's driver: the database's clock, claims that skip locked rows, NOTIFY in the
transaction, a LISTEN connection that is reopened after a failure
(`roadlink.db.drivers.postgres`)."""

from __future__ import annotations

import pytest
from sqlalchemy import Engine, select, text
from sqlalchemy.dialects import postgresql

from roadlink.db.drivers.postgres import PostgresDriver, PostgresListener, libpq_conninfo
from roadlink.db.models import Job


def test_the_clock_is_the_databases_and_claims_skip_locked_rows() -> None:
    driver = PostgresDriver("postgresql://u@h/db")
    assert str(driver.clock()) == "now()"
    claimed = driver.lock_for_claim(select(Job.id).limit(1))
    assert "FOR UPDATE SKIP LOCKED" in str(claimed.compile(dialect=postgresql.dialect()))


def test_libpq_connects_without_the_sqlalchemy_driver_name() -> None:
    url = libpq_conninfo("postgresql+psycopg://user:secret@host:5432/db")
    assert url == "postgresql://user:secret@host:5432/db"


def test_a_listener_that_cannot_connect_raises_and_tries_again_at_its_next_wait() -> None:
    listener = PostgresListener("postgresql://nobody@127.0.0.1:1/none", "roadlink_test")
    for _ in range(2):
        with pytest.raises(Exception):  # noqa: B017 - psycopg's OperationalError
            listener.wait(0.1)
        assert not listener.hears_everything
    listener.close()


def test_a_listener_reconnects_after_its_connection_is_killed(
    engine: Engine, database_url: str
) -> None:
    if engine.dialect.name != "postgresql":
        pytest.skip("LISTEN is PostgreSQL's")
    listener = PostgresDriver(database_url).listen("roadlink_test")
    try:
        listener.wait(0.0)
        assert listener.hears_everything
        with engine.begin() as connection:
            connection.execute(
                text(
                    "SELECT pg_terminate_backend(pid) FROM pg_stat_activity "
                    "WHERE query LIKE 'LISTEN roadlink_test%'"
                )
            )
        with pytest.raises(Exception):  # noqa: B017 - the terminated connection
            listener.wait(1.0)
        assert not listener.hears_everything
        listener.wait(0.0)
        assert listener.hears_everything
    finally:
        listener.close()
