"""Real databases for the tests: a fresh PostgreSQL database per use on the local server, or a
skip that says why when none answers."""

from __future__ import annotations

import socket
import uuid

import pytest
from sqlalchemy import text

from roadlink.db.engine import make_engine

POSTGRES_ADMIN_URL = "postgresql+psycopg://postgres@127.0.0.1:5432/test"

# Every backend, for parametrized fixtures; PostgreSQL tests carry the `postgres` mark.
BACKENDS = ["sqlite", pytest.param("postgresql", marks=pytest.mark.postgres)]


def postgres_answers() -> bool:
    """True when something listens on the PostgreSQL port."""
    try:
        with socket.create_connection(("127.0.0.1", 5432), timeout=0.5):
            return True
    except OSError:
        return False


def create_postgres_database() -> str:
    """A new, uniquely named database on the local server; its URL."""
    name = f"roadlink_test_{uuid.uuid4().hex[:12]}"
    admin = make_engine(POSTGRES_ADMIN_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'CREATE DATABASE "{name}"'))
    admin.dispose()
    return POSTGRES_ADMIN_URL.rsplit("/", 1)[0] + "/" + name


def drop_postgres_database(url: str) -> None:
    """Drop a database made by create_postgres_database (even with connections left open)."""
    name = url.rsplit("/", 1)[1]
    admin = make_engine(POSTGRES_ADMIN_URL, isolation_level="AUTOCOMMIT")
    with admin.connect() as connection:
        connection.execute(text(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)'))
    admin.dispose()


def require_postgres() -> None:
    """Skip, saying why, when no PostgreSQL server answers."""
    if not postgres_answers():
        pytest.skip("PostgreSQL tests skipped: nothing answers on 127.0.0.1:5432")
