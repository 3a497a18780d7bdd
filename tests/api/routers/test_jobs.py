"""Jobs through the API: selection by batch, batches or time window; status, result (JSON and
CSV, waiting), cancellation; the same numbers as the CLI."""

from __future__ import annotations

import csv
import io
import json
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.detections import Detections
from roadlink.cli import app as cli
from roadlink.queue.worker import Worker
from tests.helpers import assert_problem, detection_rows, post_csv_batch


@pytest.mark.parametrize(
    ("associator", "params"),
    [
        ("kmeans++", {}),
        ("kmeans", {"seed": 3, "n_init": 2}),
        ("svm-quadratic", {"folds": 3}),
        ("assignment", {"min_confidence": 0.3}),
    ],
)
def test_the_service_computes_what_the_cli_computes(
    client: TestClient,
    worker: Worker,
    deployment: dict[str, Any],
    paper_csv: str,
    tmp_path: Path,
    associator: str,
    params: dict[str, Any],
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv)
    created = client.post(
        "/v1/jobs", json={"batch_id": batch["id"], "associator": associator, "params": params}
    )
    assert created.status_code == 202, created.text
    assert worker.run_once()
    job_id = created.json()["id"]
    served = client.get(f"/v1/jobs/{job_id}/result")
    assert served.status_code == 200 and served.headers["content-type"] == "application/json"

    path = tmp_path / "batch.csv"
    path.write_text(paper_csv)
    args = ["associate", str(path), "--associator", associator]
    args += [f"--param={k}={v}" for k, v in params.items()]
    printed = CliRunner().invoke(cli, [*args, "--json"])
    assert printed.exit_code == 0, printed.output
    assert served.json() == json.loads(printed.stdout)
    assert served.json()["metrics"]["accuracy"] > 0  # labelled: scored
    # Links, and so confidences, only from the associator that builds targets from links.
    confidences = [t.get("confidence") for t in served.json()["targets"]]
    if associator == "assignment":
        assert all(c is not None and 0.3**9 <= c <= 1 for c in confidences)
    else:
        assert confidences == [None] * len(confidences)

    matrix = client.get(f"/v1/jobs/{job_id}/result", params={"format": "csv"})
    assert matrix.headers["content-type"].startswith("text/csv")
    printed = CliRunner().invoke(cli, [*args, "--csv"])
    assert matrix.text == printed.stdout


def test_status_progress_and_409_until_finished(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator=DEFAULT_ASSOCIATOR)
    job = client.get(f"/v1/jobs/{batch['job']['id']}").json()
    assert (job["state"], job["progress"], job["attempts"]) == ("queued", 0.0, 0)
    problem = assert_problem(client.get(f"/v1/jobs/{job['id']}/result"), 409)
    assert "queued" in problem["detail"] and "wait" in problem["detail"]
    assert worker.run_once()
    job = client.get(f"/v1/jobs/{job['id']}").json()
    assert (job["state"], job["progress"], job["attempts"], job["n_detections"]) == (
        "succeeded",
        1.0,
        1,
        100,
    )
    assert job["duration_seconds"] > 0 and job["finished_at"] >= job["started_at"]
    assert job in client.get("/v1/jobs", params={"deployment_id": deployment["id"]}).json()["items"]


def test_wait_returns_the_result_once_the_worker_finishes(
    client: TestClient, running_worker: Worker, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator=DEFAULT_ASSOCIATOR)
    result = client.get(f"/v1/jobs/{batch['job']['id']}/result", params={"wait": 10})
    assert result.status_code == 200, result.text
    assert result.json()["n_targets"] == 10 and result.json()["n_detections"] == 100


def test_a_job_over_several_batches_or_a_time_window(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    # One gateway per sensor: each vehicle's two detections arrive in different batches.
    first = post_csv_batch(
        client, deployment["id"], "position,velocity,timestamp\n0,30,1\n0,40,10\n"
    )
    second = post_csv_batch(
        client, deployment["id"], "position,velocity,timestamp\n100,30,4.3\n100,40,12.5\n"
    )
    by_batches = client.post(
        "/v1/jobs",
        json={
            "batch_ids": [first["id"], second["id"]],
            "associator": "kmeans++",
            "params": {"n_targets": 2},
        },
    )
    window = client.post(
        "/v1/jobs",
        json={
            "deployment_id": deployment["id"],
            "start": 0,
            "end": 12,
            "associator": "kmeans++",
            "params": {"n_targets": 2},
        },
    )
    assert by_batches.status_code == window.status_code == 202
    assert worker.run_once() and worker.run_once()
    both = client.get(f"/v1/jobs/{by_batches.json()['id']}/result").json()
    assert both["n_detections"] == 4 and both["n_targets"] == 2
    assert [len(t["detections"]) for t in both["targets"]] == [2, 2]
    assert both["metrics"] is None  # unlabelled
    ids = {d["detection_id"] for t in both["targets"] for d in t["detections"]}
    assert {i.split(":")[0] for i in ids} == {first["id"], second["id"]}  # qualified: d1 twice
    windowed = client.get(f"/v1/jobs/{window.json()['id']}/result").json()
    assert windowed["n_detections"] == 3  # 12.5 is outside [0, 12)


def test_the_result_says_which_parameters_assignment_ran_with(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_batch: Detections
) -> None:
    # The paper's batch timed in hours (positions in km, speeds in km/h): the seconds-sized
    # duplicate_window and timestamp_noise are held to shares of a ~3 s travel time.
    d = paper_batch
    hours = Detections(
        d.position / 1000,
        d.velocity * 3.6,
        d.timestamp / 3600,
        d.sensor_id,
        d.detection_id,
        d.target,
    )
    body = {"detections": detection_rows(hours), "associate": {"associator": "assignment"}}
    batch = client.post(f"/v1/deployments/{deployment['id']}/batches", json=body)
    assert batch.status_code == 201, batch.text
    kmeans = client.post("/v1/jobs", json={"batch_id": batch.json()["id"], "associator": "kmeans"})
    assert kmeans.status_code == 202, kmeans.text
    assert worker.run_once() and worker.run_once()

    result = client.get(f"/v1/jobs/{batch.json()['job']['id']}/result").json()
    asked, effective = result["params"], result["effective_params"]
    assert (asked["duplicate_window"], asked["timestamp_noise"]) == (0.5, 0.02)
    assert 0.1 / 3600 < effective["duplicate_window"] < 1.0 / 3600
    assert effective["timestamp_noise"] < 0.1 / 3600
    assert effective["max_skip"] == asked["max_skip"] == 2
    assert "effective_params" not in client.get(f"/v1/jobs/{kmeans.json()['id']}/result").json()


def test_job_requests_that_cannot_run(
    client: TestClient, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv)
    problem = assert_problem(client.post("/v1/jobs", json={"associator": "kmeans"}), 422)
    assert "exactly one of" in problem["detail"]
    problem = assert_problem(
        client.post("/v1/jobs", json={"deployment_id": deployment["id"], "start": 5, "end": 5}), 422
    )
    assert "empty" in problem["detail"]
    problem = assert_problem(
        client.post("/v1/jobs", json={"deployment_id": deployment["id"], "start": 1e6}), 422
    )
    assert "no detections" in problem["detail"]
    problem = assert_problem(
        client.post("/v1/jobs", json={"batch_ids": [batch["id"], deployment["id"]]}), 422
    )
    assert problem["errors"][0]["field"] == "batch_ids.1"
    problem = assert_problem(
        client.post("/v1/jobs", json={"batch_id": batch["id"], "params": {"colour": 1}}), 422
    )
    assert "colour" in problem["detail"]
    one_sensor = post_csv_batch(client, deployment["id"], "position,velocity,timestamp\n0,30,1\n")
    problem = assert_problem(client.post("/v1/jobs", json={"batch_id": one_sensor["id"]}), 422)
    assert "one sensor position" in problem["detail"]
    assert_problem(client.get("/v1/jobs/00000000-0000-0000-0000-000000000000"), 404)
    assert_problem(client.get("/v1/jobs/not-a-uuid"), 422)


def test_cancel(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_csv: str
) -> None:
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans")
    job_id = batch["job"]["id"]
    cancelled = client.post(f"/v1/jobs/{job_id}/cancel")
    assert cancelled.status_code == 200 and cancelled.json()["state"] == "cancelled"
    assert client.post(f"/v1/jobs/{job_id}/cancel").json()["state"] == "cancelled"
    assert not worker.run_once()  # nothing left to run
    problem = assert_problem(client.get(f"/v1/jobs/{job_id}/result"), 409)
    assert "cancelled" in problem["detail"]

    done = client.post("/v1/jobs", json={"batch_id": batch["id"]}).json()
    assert worker.run_once()
    problem = assert_problem(client.post(f"/v1/jobs/{done['id']}/cancel"), 409)
    assert "succeeded" in problem["detail"]


def test_result_csv_cannot_run_as_a_spreadsheet_formula(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    """Ids are the gateway's text: written into a CSV, text such as =HYPERLINK(...) would run
    when an analyst opens the file (OWASP CSV injection), so such cells start with a quote."""
    ids = ['=HYPERLINK("http://evil.example","x")', "+1", "@d3", "-d4"]
    text = "position,velocity,timestamp,sensor_id,detection_id\n" + "".join(
        f'{p},30.0,{t},{s},"{i.replace(chr(34), 2 * chr(34))}"\n'
        for p, t, s, i in zip(
            (0.0, 100.0, 0.0, 100.0), (0.0, 3.3, 9.0, 12.3), ("=S1", "@S2") * 2, ids, strict=True
        )
    )
    batch = post_csv_batch(client, deployment["id"], text)
    job = client.post("/v1/jobs", json={"batch_id": batch["id"]}).json()["id"]
    assert worker.run_once()
    matrix = client.get(f"/v1/jobs/{job}/result", params={"format": "csv"})
    rows = list(csv.reader(io.StringIO(matrix.text)))
    cells = [cell for row in rows for cell in row]
    assert "'=S1_detection_id" in cells and "'@S2_velocity" in cells
    assert {"'" + i for i in ids} <= set(cells)
    assert not [c for c in cells if c[:1] in ("=", "+", "@") or (c[:1] == "-" and c[1:2].isalpha())]
    # The JSON result keeps the ids as they were sent.
    served = client.get(f"/v1/jobs/{job}/result").json()
    assert {d["detection_id"] for t in served["targets"] for d in t["detections"]} == set(ids)
