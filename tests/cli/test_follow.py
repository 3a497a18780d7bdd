"""`roadlink follow` against a real `roadlink serve` with a worker: the vehicles a live
association publishes, as JSON lines and as CSV, by the feed's long poll."""

from __future__ import annotations

import json

import httpx
import pytest
from typer.testing import CliRunner

from roadlink.association import associate
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.cli import app
from tests.cli.conftest import Served

pytestmark = pytest.mark.slow

runner = CliRunner()


def test_follow_prints_the_vehicles_a_live_association_publishes(served: Served) -> None:
    d = read_detections_csv(served.csv.read_text())
    with httpx.Client(
        base_url=served.url, headers={"Authorization": f"Bearer {served.key}"}, timeout=30
    ) as http:
        road = http.post("/v1/deployments", json={"name": "followed"}).json()["id"]
        # Each gateway posts its whole 40 s at once: a lateness above that keeps them on time.
        started = http.put(f"/v1/deployments/{road}/live", json={"lateness": 60})
        assert started.status_code == 200
        for sensor in sorted(set(d.sensor_id.tolist())):  # a gateway per sensor
            posted = http.post(
                f"/v1/deployments/{road}/batches",
                content=write_detections_csv(d.take((d.sensor_id == sensor).nonzero()[0])),
                headers={"content-type": "text/csv"},
            )
            assert posted.status_code == 201, posted.text
        http.post(f"/v1/deployments/{road}/live/flush")
        # Each long poll returns as soon as the worker publishes, until the flush is done.
        page = http.get(f"/v1/deployments/{road}/vehicles?wait=30").json()
        assert page["items"]
        while http.get(f"/v1/deployments/{road}/live").json()["pending"]:
            page = http.get(page["next"].replace("wait=30", "wait=1")).json()
    done = runner.invoke(app, ["follow", "--deployment", road, "--until-idle"], env=served.env)
    assert done.exit_code == 0, done.output
    vehicles = [json.loads(line) for line in done.stdout.splitlines()]
    assert [v["vehicle_id"] for v in vehicles] == [f"V{k}" for k in range(1, 11)]
    offline = associate(d, "assignment")
    assert sum(len(v["detections"]) for v in vehicles) == len(offline.detections)
    # Resumed after the fourth, it prints the rest.
    after = vehicles[3]["cursor"]
    rest = runner.invoke(
        app, ["follow", "--deployment", road, "--until-idle", "--after", after], env=served.env
    )
    assert [json.loads(line)["vehicle_id"] for line in rest.stdout.splitlines()] == [
        f"V{k}" for k in range(5, 11)
    ]
    as_csv = runner.invoke(
        app, ["follow", "--deployment", road, "--until-idle", "--csv"], env=served.env
    )
    lines = as_csv.stdout.splitlines()
    assert lines[0].startswith("vehicle_id,confidence,detection_id")
    assert len(lines) == 1 + len(d)
