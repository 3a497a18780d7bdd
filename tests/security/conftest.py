"""Helpers for the security tests: keys of each scope, row counts of every table, and a live
`roadlink serve` on a real SQLite file (tests/live_server.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
from sqlalchemy import Engine, func, select

from roadlink.db.models import Base

# The API tests' data fixtures: the paper's large scenario, as detections and as CSV.
from tests.api.conftest import MakeKey, deployment, make_key, paper_batch, paper_csv  # noqa: F401
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env  # noqa: F401


def bearer(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def row_counts(engine: Engine) -> dict[str, int]:
    """The number of rows in every table of the schema."""
    with engine.connect() as connection:
        return {
            name: int(connection.scalar(select(func.count()).select_from(table)) or 0)
            for name, table in Base.metadata.tables.items()
        }


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[LiveServer]:
    """An unstarted live server on a fresh SQLite file (the test starts it, with settings)."""
    server = LiveServer(directory=tmp_path, env=sqlite_env(tmp_path), port=free_port())
    yield server
    server.stop()
