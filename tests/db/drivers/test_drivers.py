"""Choosing the driver, and the contract every driver keeps: news sent by a transaction is
heard at its commit, never when it rolls back (`roadlink.db.drivers`)."""

from __future__ import annotations

from sqlalchemy import Engine
from sqlalchemy.orm import Session

from roadlink.db.drivers import driver_for, driver_of
from roadlink.db.drivers.postgres import PostgresDriver
from roadlink.db.drivers.sqlite import SqliteDriver


def test_the_driver_is_chosen_from_the_url() -> None:
    assert isinstance(driver_for("sqlite:///x.db"), SqliteDriver)
    assert isinstance(driver_for("sqlite://"), SqliteDriver)
    assert isinstance(driver_for("postgresql+psycopg://u:p@h:5/db"), PostgresDriver)
    assert isinstance(driver_for("postgresql://u@h/db"), PostgresDriver)


def test_a_session_asks_its_engines_driver_once(engine: Engine) -> None:
    with Session(engine) as first, Session(engine) as second:
        assert driver_of(first) is driver_of(second)
        assert driver_of(first).name == engine.dialect.name


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


def test_another_channel_hears_nothing(engine: Engine, database_url: str) -> None:
    driver = driver_for(database_url)
    other = driver.listen("roadlink_other")
    try:
        other.wait(0.0)
        with Session(engine) as session, session.begin():
            driver.notify(session, "roadlink_test", ["a"])
        assert other.wait(0.3) is None
    finally:
        other.close()


def test_a_prebuilt_statement_is_built_once_per_driver_and_kind_of_clock(engine: Engine) -> None:
    """Built at its first use and reused; the driver's clock is a parameter where it is a time
    (SQLite), written into the statement where it is SQL (PostgreSQL); a caller's `now` is bound
    on either, in a statement of its own."""
    from datetime import UTC, datetime

    from sqlalchemy import literal, select

    from roadlink.db.drivers import prebuilt

    built: list[bool] = []

    def build(driver: object, clock: object, bound: bool) -> object:
        built.append(bound)
        return select(literal(1)).where(clock is not None)

    name = f"test-{engine.dialect.name}-{id(built)}"
    with Session(engine) as session:
        first, params = prebuilt(session, name, build)
        again, _ = prebuilt(session, name, build)
        assert again is first
        on_sqlite = engine.dialect.name == "sqlite"
        assert ("now" in params) is on_sqlite
        when = datetime(2026, 1, 2, tzinfo=UTC)
        given, given_params = prebuilt(session, name, build, now=when)
        assert given_params == {"now": when}
        assert prebuilt(session, name, build, now=when)[0] is given
    assert built == ([True] if on_sqlite else [False, True])
