"""SQLite's driver: durable connections, this host's clock, no claim lock, news after the commit
in this process and by the doorbell (`roadlink.db.drivers.sqlite`)."""

from __future__ import annotations

import sqlite3
from datetime import datetime
from pathlib import Path
from types import SimpleNamespace

import pytest
from sqlalchemy import select, text
from sqlalchemy.dialects import sqlite
from sqlalchemy.orm import Session

from roadlink.db.drivers import doorbell
from roadlink.db.drivers.sqlite import (
    SqliteDriver,
    SqliteListener,
    _drop_connections_that_cannot_write,
)
from roadlink.db.engine import engine_for, make_engine
from roadlink.db.models import Job
from roadlink.settings import Settings


@pytest.mark.parametrize(("synchronous", "level"), [(None, 1), ("normal", 1), ("full", 2)])
def test_connections_use_wal_synced_as_set_and_enforce_foreign_keys(
    tmp_path: Path, synchronous: str | None, level: int
) -> None:
    """ROADLINK_SQLITE_SYNCHRONOUS: normal (1) by default, full (2) when asked."""
    url = f"sqlite:///{tmp_path / 'x.db'}"
    engine = (
        make_engine(url)
        if synchronous is None
        else make_engine(url, sqlite_synchronous=synchronous)
    )
    with engine.connect() as connection:
        pragma = {
            name: connection.execute(text(f"PRAGMA {name}")).scalar()
            for name in ("journal_mode", "synchronous", "foreign_keys", "busy_timeout")
        }
    engine.dispose()
    assert pragma == {
        "journal_mode": "wal",
        "synchronous": level,
        "foreign_keys": 1,
        "busy_timeout": 30000,
    }


def test_an_unknown_synchronous_level_is_refused(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match="sqlite_synchronous"):
        make_engine(f"sqlite:///{tmp_path / 'x.db'}", sqlite_synchronous="off")


def test_the_service_engine_follows_its_settings(tmp_path: Path) -> None:
    settings = Settings(database_url=f"sqlite:///{tmp_path / 'x.db'}", sqlite_synchronous="full")
    engine = engine_for(settings)
    with engine.connect() as connection:
        assert connection.execute(text("PRAGMA synchronous")).scalar() == 2
    engine.dispose()


@pytest.mark.parametrize(
    ("error", "lost"),
    [
        ("attempt to write a readonly database", True),
        ("disk I/O error", True),
        ("unable to open database file", True),
        ("database or disk is full", True),
        ("no such table: batch", False),
    ],
)
def test_an_error_that_leaves_a_connection_unable_to_write_counts_as_lost(
    error: str, lost: bool
) -> None:
    """SQLAlchemy then drops the pool's connections, so the service recovers by itself once
    the storage does."""
    context = SimpleNamespace(
        original_exception=sqlite3.OperationalError(error), is_disconnect=False
    )
    _drop_connections_that_cannot_write(context)  # type: ignore[arg-type]
    assert context.is_disconnect is lost


def test_the_clock_is_this_hosts_and_claims_take_no_lock() -> None:
    driver = SqliteDriver("sqlite://")
    assert isinstance(driver.clock(), datetime)
    claimed = driver.lock_for_claim(select(Job.id).limit(1))
    assert "FOR UPDATE" not in str(claimed.compile(dialect=sqlite.dialect()))


def test_a_session_notifies_in_each_of_its_transactions(tmp_path: Path) -> None:
    database_url = f"sqlite:///{tmp_path / 'x.db'}"
    engine = make_engine(database_url)
    driver = SqliteDriver(database_url)
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


def test_a_listener_hears_other_processes_by_the_doorbell(tmp_path: Path) -> None:
    database_url = f"sqlite:///{tmp_path / 'x.db'}"
    listener = SqliteListener(database_url, "roadlink_test")
    try:
        doorbell.ring(database_url, "roadlink_test", b"job-1\njob-2")
        assert listener.wait(5.0) == ["job-1", "job-2"]
        doorbell.ring(database_url, "roadlink_test", b"")
        assert listener.wait(5.0) == [], "a ring without news still wakes"
        assert listener.wait(0.05) is None
    finally:
        listener.close()


def test_news_of_this_process_is_heard_once(tmp_path: Path) -> None:
    database_url = f"sqlite:///{tmp_path / 'x.db'}"
    listener = SqliteListener(database_url, "roadlink_test")
    try:
        listener.hear(["job-1"])
        doorbell.ring(database_url, "roadlink_test", b"job-1")  # the same news, rung
        assert listener.wait(5.0) == ["job-1"]
        assert listener.wait(0.05) is None
    finally:
        listener.close()


def test_an_in_memory_database_hears_this_process_only() -> None:
    listener = SqliteListener("sqlite://", "roadlink_test")
    try:
        assert listener.wait(0.05) is None
        listener.hear(["a"])
        assert listener.wait(5.0) == ["a"]
        assert not listener.hears_everything
        assert not listener.hears_others  # no doorbell: its users poll often
    finally:
        listener.close()


def test_a_database_file_hears_other_processes_by_its_doorbell(tmp_path: Path) -> None:
    listener = SqliteListener(f"sqlite:///{tmp_path / 'x.db'}", "roadlink_test")
    try:
        assert listener.hears_others and not listener.hears_everything  # a ring may be lost
    finally:
        listener.close()
