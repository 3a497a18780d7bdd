"""The security tests' live server: `roadlink serve` on a real SQLite file (live_server.py)."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.live_server import LiveServer, free_port, sqlite_env


@pytest.fixture
def live_server(tmp_path: Path) -> Iterator[LiveServer]:
    """An unstarted live server on a fresh SQLite file (the test starts it, with settings)."""
    server = LiveServer(directory=tmp_path, env=sqlite_env(tmp_path), port=free_port())
    yield server
    server.stop()
