"""The drivers: each database's engine setup, clock, claim lock and notifications."""

from __future__ import annotations

from datetime import datetime

from sqlalchemy import Engine, select, text
from sqlalchemy.dialects import postgresql, sqlite
from sqlalchemy.orm import Session

from roadlink.db.drivers import driver_for, driver_of
from roadlink.db.drivers.postgres import PostgresDriver, libpq_conninfo
from roadlink.db.drivers.sqlite import SqliteDriver
from roadlink.db.engine import make_engine
from roadlink.db.models import Job


def test_the_driver_is_chosen_from_the_url() -> None:
    assert isinstance(driver_for("sqlite:///x.db"), SqliteDriver)
    assert isinstance(driver_for("sqlite://"), SqliteDriver)
    assert isinstance(driver_for("postgresql+psycopg://u:p@h:5/db"), PostgresDriver)
    assert isinstance(driver_for("postgresql://u@h/db"), PostgresDriver)


def test_a_session_asks_its_engines_driver_once(engine: Engine) -> None:
    with Session(engine) as first, Session(engine) as second:
        assert driver_of(first) is driver_of(second)
        assert driver_of(first).name == engine.dialect.name


def test_sqlite_connections_are_durable_and_enforce_foreign_keys(tmp_path) -> None:
    engine = make_engine(f"sqlite:///{tmp_path / 'x.db'}")
    with engine.connect() as connection:
        pragma = {
            name: connection.execute(text(f"PRAGMA {name}")).scalar()
            for name in ("journal_mode", "synchronous", "foreign_keys", "busy_timeout")
        }
    engine.dispose()
    assert pragma == {
        "journal_mode": "wal",
        "synchronous": 2,
        "foreign_keys": 1,
        "busy_timeout": 30000,
    }


def test_only_postgres_locks_the_claims_candidate() -> None:
    query = select(Job.id).limit(1)
    on_postgres = PostgresDriver("postgresql://u@h/db").lock_for_claim(query)
    on_sqlite = SqliteDriver("sqlite://").lock_for_claim(query)
    assert "FOR UPDATE SKIP LOCKED" in str(on_postgres.compile(dialect=postgresql.dialect()))
    assert "FOR UPDATE" not in str(on_sqlite.compile(dialect=sqlite.dialect()))


def test_the_clock_is_the_databases_on_postgres_and_this_hosts_on_sqlite() -> None:
    assert isinstance(SqliteDriver("sqlite://").clock(), datetime)
    assert str(PostgresDriver("postgresql://u@h/db").clock()) == "now()"


def test_libpq_connects_without_the_sqlalchemy_driver_name() -> None:
    url = libpq_conninfo("postgresql+psycopg://user:secret@host:5432/db")
    assert url == "postgresql://user:secret@host:5432/db"


def test_news_is_heard_at_commit_never_on_rollback(engine: Engine, database_url: str) -> None:
    driver = driver_for(database_url)
    listener = driver.listen("roadlink_test")
    try:
        listener.wait(0.0)  # PostgreSQL: the LISTEN connection opens at the first wait
        with Session(engine) as session, session.begin():
            driver.notify(session, "roadlink_test", ["a", "b"])
            session.rollback()
        assert listener.wait(0.3) is None
        with Session(engine) as session, session.begin():
            driver.notify(session, "roadlink_test", ["a", "b"])
        heard = listener.wait(5.0) or []
        heard += listener.wait(0.3) or []  # PostgreSQL: one notification per wait
        assert sorted(heard) == ["a", "b"]
    finally:
        listener.close()


def test_a_sqlite_session_notifies_in_each_of_its_transactions(tmp_path) -> None:
    database_url = f"sqlite:///{tmp_path / 'x.db'}"
    engine = make_engine(database_url)
    driver = driver_for(database_url)
    listener = driver.listen("roadlink_test")
    try:
        with Session(engine) as session:
            with session.begin():
                driver.notify(session, "roadlink_test", ["1"])
            with session.begin():
                driver.notify(session, "roadlink_test", ["2"])
        assert listener.wait(5.0) == ["1", "2"]
    finally:
        listener.close()
        engine.dispose()
