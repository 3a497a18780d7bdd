"""The CLI's remote commands against a real server: `roadlink serve --workers 1`, shared by the
tests of a module."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path
from typing import NamedTuple

import httpx
import pytest

from roadlink.association.csvio import write_detections_csv
from roadlink.simulation import preset, simulate
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env


class Served(NamedTuple):
    url: str
    key: str
    deployment: str
    csv: Path

    @property
    def env(self) -> dict[str, str]:
        return {"ROADLINK_URL": self.url, "ROADLINK_KEY": self.key}


@pytest.fixture(scope="module")
def served(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Served]:
    """`roadlink serve --workers 1`, an admin key, a deployment and a labelled CSV."""
    directory = tmp_path_factory.mktemp("remote")
    live = LiveServer(directory, sqlite_env(directory), free_port())
    key = roadlink("keys", "create", "--scope", "admin", env=live.env, cwd=directory).strip()
    live.start(workers=1)
    try:
        headers = {"Authorization": f"Bearer {key}"}
        created = httpx.post(
            f"{live.url}/v1/deployments", json={"name": "remote"}, headers=headers, timeout=30
        )
        csv = directory / "large.csv"
        csv.write_text(write_detections_csv(simulate(preset("large"), seed=1).detections))
        yield Served(live.url, key, created.json()["id"], csv)
    finally:
        live.stop()
