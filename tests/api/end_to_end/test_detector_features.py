"""Detector features (lane, length, vehicle_class) end to end through the API: posted as JSON
and CSV, stored, associated by a worker, and served back in the result JSON, its CSV and the
job page; refused whole, naming row and field, when wrong; absent, so results are as they
always were, when no detection reports them."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine
from typer.testing import CliRunner

from roadlink.association import associate
from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.cli import app as cli
from roadlink.queue.worker import Worker
from roadlink.simulation import preset, simulate
from tests.helpers import assert_problem, detection_rows, row_counts, with_features

FEATURES = ("lane", "length", "vehicle_class")


@pytest.fixture
def featured() -> Detections:
    """The paper's large scenario with false alarms; lanes from the first four sensors only."""
    d = simulate(preset("large", false_alarm_rate=0.05), seed=5).detections
    return with_features(d, lane_sensors=4)


def _batches(client: TestClient, deployment: dict[str, Any]) -> str:
    return f"/v1/deployments/{deployment['id']}/batches"


def _post_json(
    client: TestClient, url: str, d: Detections, associator: str | None = None
) -> dict[str, Any]:
    body: dict[str, Any] = {"detections": detection_rows(d)}
    if associator is not None:
        body["associate"] = {"associator": associator}
    posted = client.post(url, json=body)
    assert posted.status_code == 201, posted.text
    return dict(posted.json())


def _post_csv(client: TestClient, url: str, text: str, **params: str) -> dict[str, Any]:
    posted = client.post(url, content=text, headers={"content-type": "text/csv"}, params=params)
    assert posted.status_code == 201, posted.text
    return dict(posted.json())


def _result(client: TestClient, worker: Worker, job_id: str) -> tuple[dict[str, Any], str]:
    assert worker.run_once()
    served = client.get(f"/v1/jobs/{job_id}/result")
    assert served.status_code == 200, served.text
    matrix = client.get(f"/v1/jobs/{job_id}/result", params={"format": "csv"})
    assert matrix.status_code == 200, matrix.text
    return served.json(), matrix.text


def _served_rows(document: dict[str, Any]) -> dict[str, dict[str, Any]]:
    rows = [r for t in document["targets"] for r in t["detections"]] + document["unassigned"]
    return {r["detection_id"]: r for r in rows}


@pytest.mark.parametrize("body", ["json", "csv"])
def test_features_posted_come_back_in_the_result_as_the_cli_gives_them(
    client: TestClient,
    worker: Worker,
    deployment: dict[str, Any],
    featured: Detections,
    tmp_path: Path,
    body: str,
) -> None:
    url = _batches(client, deployment)
    text = write_detections_csv(featured)
    if body == "json":
        batch = _post_json(client, url, featured, associator="assignment")
    else:
        batch = _post_csv(client, url, text, associator="assignment")
    document, matrix = _result(client, worker, batch["job"]["id"])

    served = _served_rows(document)
    assert len(served) == len(featured)
    for i, detection_id in enumerate(featured.detection_id.tolist()):
        row = served[detection_id]
        assert [row[name] for name in FEATURES] == [
            featured.feature_values(name)[i] for name in FEATURES
        ]
    assert any(r["lane"] is None for r in served.values())  # sensors without lanes: null
    assert all({"length", "vehicle_class"} <= t.keys() for t in document["targets"])
    header = next(csv.reader(io.StringIO(matrix)))
    assert {"S1_lane", "S1_length", "S1_vehicle_class", "S10_lane"} <= set(header)
    # Localisation carries each vehicle's length and class as the result's targets give them.
    first = document["targets"][0]
    target = client.get(f"/v1/jobs/{batch['job']['id']}/targets/T1").json()
    assert (target["length"], target["vehicle_class"]) == (
        first["length"],
        first["vehicle_class"],
    )
    at = first["detections"][0]["timestamp"]
    positions = client.get(f"/v1/jobs/{batch['job']['id']}/positions", params={"t": at}).json()
    by_name = {t["target"]: t for t in document["targets"]}
    assert positions["targets"]
    for p in positions["targets"]:
        assert p["length"] == by_name[p["target"]]["length"]
        assert p["vehicle_class"] == by_name[p["target"]]["vehicle_class"]

    # The CLI on the same detections prints the same document and matrix.
    path = tmp_path / "featured.csv"
    path.write_text(text)
    printed = CliRunner().invoke(cli, ["associate", str(path), "--json"])
    assert printed.exit_code == 0, printed.output
    assert document == json.loads(printed.stdout)
    printed = CliRunner().invoke(cli, ["associate", str(path), "--csv"])
    assert matrix == printed.stdout


def test_without_features_the_result_is_what_it_always_was(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_batch: Detections
) -> None:
    batch = _post_json(client, _batches(client, deployment), paper_batch, associator="assignment")
    document, matrix = _result(client, worker, batch["job"]["id"])
    keys = {k for r in _served_rows(document).values() for k in r}
    assert keys == {"detection_id", "sensor_id", "position", "velocity", "timestamp"} | {
        "link_confidence"
    }
    assert {k for t in document["targets"] for k in t} == {"target", "confidence", "detections"}
    job = batch["job"]["id"]
    at = document["targets"][0]["detections"][0]["timestamp"]
    positions = client.get(f"/v1/jobs/{job}/positions", params={"t": at}).json()
    assert {k for p in positions["targets"] for k in p} == {"target", "position", "velocity"}
    target = client.get(f"/v1/jobs/{job}/targets/T1").json()
    assert not {"length", "vehicle_class"} & target.keys()
    assert not [h for h in matrix.splitlines()[0].split(",") if h.endswith(FEATURES)]
    expected = associate(paper_batch, "assignment")
    assert document == json.loads(json.dumps(expected.to_dict()))
    assert matrix == expected.to_matrix_csv()


def test_a_job_over_a_batch_with_lanes_and_one_without(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_batch: Detections
) -> None:
    """Two gateways: the first five sensors report lanes, lengths and classes, the others
    nothing; one job over both batches."""
    d = paper_batch
    near = with_features(d.take(d.position < 500))
    far = d.take(d.position >= 500)
    url = _batches(client, deployment)
    ids = [
        _post_json(client, url, near)["id"],
        _post_csv(client, url, write_detections_csv(far))["id"],
    ]
    job = client.post("/v1/jobs", json={"batch_ids": ids, "associator": "assignment"})
    assert job.status_code == 202, job.text
    document, matrix = _result(client, worker, job.json()["id"])
    served = _served_rows(document)
    for i, detection_id in enumerate(near.detection_id.tolist()):
        assert served[detection_id]["lane"] == near.feature_values("lane")[i]
    for detection_id in far.detection_id.tolist():
        assert [served[detection_id][name] for name in FEATURES] == [None, None, None]
    rows = list(csv.DictReader(io.StringIO(matrix)))
    assert all(r["S10_lane"] == r["S10_length"] == r["S10_vehicle_class"] == "" for r in rows)
    assert any(r["S1_lane"] != "" for r in rows)
    # Every target's length and class come from its first five sensors.
    assert all(t["length"] is not None and t["vehicle_class"] for t in document["targets"])


@pytest.mark.parametrize("with_them", [True, False], ids=["features", "paper"])
def test_the_job_page_shows_the_features_when_there_are_some(
    client: TestClient,
    worker: Worker,
    deployment: dict[str, Any],
    featured: Detections,
    with_them: bool,
) -> None:
    posted = featured if with_them else featured.without_features()
    batch = _post_json(client, _batches(client, deployment), posted, associator="assignment")
    assert worker.run_once()
    page = client.get(f"/jobs/{batch['job']['id']}")
    assert page.status_code == 200, page.text
    shown = [f">{title}</th>" in page.text for title in ("Lane", "Length", "Class")]
    assert shown == [with_them] * 3
    assert (">truck</td>" in page.text) == with_them
    assert (f">{featured.length[0]:.2f} m</td>" in page.text) == with_them


# A bad value in row 4 of a JSON batch: the field, the value, and what the problem says.
BAD_JSON = [
    ("lane", -1, "whole number from 0 to 255"),
    ("lane", 1.5, "whole number from 0 to 255"),
    ("lane", 256, "whole number from 0 to 255"),
    ("lane", "2", "must be a JSON number or null"),
    ("lane", True, "must be a JSON number or null"),
    ("length", 0, "> 0 and at most 100"),
    ("length", -4.2, "> 0 and at most 100"),
    ("length", 100.5, "> 0 and at most 100"),
    ("length", 1e300, "beyond the limit"),
    ("length", 10**13, "beyond the limit"),
    ("length", "4.5", "must be a JSON number or null"),
    ("vehicle_class", 3, "must be a string"),
    ("vehicle_class", "x" * 33, "at most 32 printable characters"),
    ("vehicle_class", "car\x00", "at most 32 printable characters"),
    ("vehicle_class", ["car"], "must be a string"),
]


@pytest.mark.parametrize(("name", "value", "message"), BAD_JSON)
def test_a_bad_feature_in_json_names_row_and_field_and_stores_nothing(
    client: TestClient,
    engine: Engine,
    deployment: dict[str, Any],
    featured: Detections,
    name: str,
    value: object,
    message: str,
) -> None:
    before = row_counts(engine)
    rows = detection_rows(featured)
    rows[3][name] = value
    posted = client.post(_batches(client, deployment), json={"detections": rows, "associate": {}})
    problem = assert_problem(posted, 422)
    assert [(e["row"], e["field"], e["pointer"]) for e in problem["errors"]] == [
        (4, name, f"/detections/3/{name}")
    ]
    assert message in problem["errors"][0]["message"]
    assert row_counts(engine) == before


# A bad cell in data row 2 of a CSV batch.
BAD_CSV = [
    ("lane", "-1", "whole number from 0 to 255"),
    ("lane", "left", "must be a number"),
    ("lane", "0.5", "whole number from 0 to 255"),
    ("length", "0", "> 0 and at most 100"),
    ("length", "1e3", "> 0 and at most 100"),
    ("length", "nan", "must be finite"),
    ("length", "4,5", "has 9 fields"),
    ("vehicle_class", "y" * 40, "at most 32 printable characters"),
]


@pytest.mark.parametrize(("name", "cell", "message"), BAD_CSV)
def test_a_bad_feature_in_csv_names_row_and_field_and_stores_nothing(
    client: TestClient,
    engine: Engine,
    deployment: dict[str, Any],
    name: str,
    cell: str,
    message: str,
) -> None:
    before = row_counts(engine)
    bad = {"lane": "1", "length": "4.5", "vehicle_class": "car", name: cell}
    text = (
        "position,velocity,timestamp,sensor_id,detection_id,lane,length,vehicle_class\n"
        "0,30,1,S1,d1,1,4.5,car\n"
        f"0,31,2,S1,d2,{bad['lane']},{bad['length']},{bad['vehicle_class']}\n"
        "100,30,4.3,S2,d3,1,4.5,car\n"
    )
    posted = client.post(
        _batches(client, deployment), content=text, headers={"content-type": "text/csv"}
    )
    problem = assert_problem(posted, 422)
    assert problem["errors"][0]["row"] == 2
    if "fields" not in message:
        assert [e["field"] for e in problem["errors"]] == [name]
    assert message in problem["errors"][0]["message"]
    assert row_counts(engine) == before
