"""A job's result drawn and localised over the API: the plot (PNG, SVG), every target's position
at a time, one target's trajectory; the same answers as the core on the same detections."""

from __future__ import annotations

import json
import re
import uuid
import xml.etree.ElementTree as ET
from dataclasses import asdict
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from roadlink.api.jobresults import JobResultCache
from roadlink.association import associate
from roadlink.association.csvio import read_detections_csv
from roadlink.association.localisation import positions_at, sample_trajectory
from roadlink.association.result import AssociationResult
from roadlink.association.scores import wrongly_grouped
from roadlink.db import repository
from roadlink.db.engine import make_session_factory
from roadlink.queue.worker import Worker
from tests.helpers import MakeKey, assert_problem, bearer, post_csv_batch

SVG = "{http://www.w3.org/2000/svg}"
PNG_SIGNATURE = b"\x89PNG\r\n\x1a\n"
# K-means++ groups the paper's large scenario (seed 5) imperfectly: some detections are wrongly
# grouped, so the highlight is exercised.
ASSOCIATOR = "kmeans++"


@pytest.fixture
def local(paper_csv: str) -> AssociationResult:
    """What the core computes from the same CSV (the CLI's answer)."""
    return associate(read_detections_csv(paper_csv), ASSOCIATOR)


@pytest.fixture
def done(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_csv: str
) -> dict[str, Any]:
    """A succeeded job over the paper batch: its batch (with the job in `job`)."""
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator=ASSOCIATOR)
    assert worker.run_once()
    return batch


def test_the_png_plot(client: TestClient, done: dict[str, Any]) -> None:
    response = client.get(f"/v1/jobs/{done['job']['id']}/plot")
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "image/png"
    assert response.content.startswith(PNG_SIGNATURE)
    backprojected = client.get(
        f"/v1/jobs/{done['job']['id']}/plot", params={"kind": "backprojected", "format": "png"}
    )
    assert backprojected.content.startswith(PNG_SIGNATURE)
    assert backprojected.content != response.content


@pytest.mark.parametrize("kind", ["time-space", "backprojected"])
def test_the_svg_plot_names_every_target_and_rings_the_wrong_ones(
    client: TestClient, done: dict[str, Any], local: AssociationResult, kind: str
) -> None:
    response = client.get(
        f"/v1/jobs/{done['job']['id']}/plot", params={"kind": kind, "format": "svg"}
    )
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("image/svg+xml")
    root = ET.fromstring(response.content)
    assert root.tag == f"{SVG}svg"
    ids = {g.get("id") for g in root.iter(f"{SVG}g")}
    assert {f"target-T{k + 1}" for k in range(local.n_targets)} <= ids
    # The labels came back from the stored detections: the same detections are highlighted as
    # on the core's own result (the stored result JSON does not hold the labels).
    wrong = int(wrongly_grouped(local.groups, local.detections.target).sum())
    assert wrong > 0, "the scenario should have wrongly grouped detections"
    assert "wrongly-grouped" in ids
    legend = " ".join(t.text or "" for t in root.iter(f"{SVG}text"))
    assert f"wrongly grouped ({wrong})" in legend


def test_the_result_is_rebuilt_with_its_labels_and_cached(
    client: TestClient, done: dict[str, Any], engine: Engine, local: AssociationResult
) -> None:
    served = client.get(f"/v1/jobs/{done['job']['id']}/result").json()
    with make_session_factory(engine)() as session:
        job = repository.get_job(session, job_id=uuid.UUID(done["job"]["id"]))
        assert job is not None
        rebuilt = repository.load_job_association(session, job=job)
    assert rebuilt is not None
    # Same targets, same detections, and the metrics scored again equal the stored ones.
    assert json.loads(json.dumps(rebuilt.to_dict())) == served
    assert rebuilt.metrics == local.metrics
    cache = JobResultCache()
    calls = []

    def load() -> AssociationResult:
        calls.append(1)
        return rebuilt

    assert cache.get(job.id, load) is cache.get(job.id, load)
    assert len(calls) == 1


def test_positions_agree_with_the_core(
    client: TestClient, done: dict[str, Any], local: AssociationResult
) -> None:
    times = local.detections.timestamp
    middle = float((times.min() + times.max()) / 2)
    on_road = {}
    for t in (float(times.min()), middle, float(times.max())):
        response = client.get(f"/v1/jobs/{done['job']['id']}/positions", params={"t": t})
        assert response.status_code == 200, response.text
        body = response.json()
        expected = positions_at(local, t)
        assert body["time"] == t
        assert [p["target"] for p in body["targets"]] == [p.target for p in expected]
        for got, want in zip(body["targets"], expected, strict=True):
            assert got["position"] == pytest.approx(want.position, rel=1e-12, abs=1e-9)
            assert got["velocity"] == pytest.approx(want.velocity, rel=1e-12, abs=1e-9)
        on_road[t] = len(expected)
    assert on_road[middle] > 0, "the middle of the run should have targets on the road"
    before = client.get(f"/v1/jobs/{done['job']['id']}/positions", params={"t": -1e6})
    assert before.json() == {"time": -1e6, "targets": []}


@pytest.mark.parametrize("step", [None, 0.25])
def test_a_targets_trajectory_agrees_with_the_core(
    client: TestClient, done: dict[str, Any], local: AssociationResult, step: float | None
) -> None:
    params = {} if step is None else {"step": step}
    for target in ("T1", f"T{local.n_targets}"):
        response = client.get(f"/v1/jobs/{done['job']['id']}/targets/{target}", params=params)
        assert response.status_code == 200, response.text
        want = json.loads(json.dumps(asdict(sample_trajectory(local, target, step))))
        want["segments"] = want.pop("legs")  # the API's word for the core's legs
        for segment in want["segments"]:
            del segment["target"]  # implied by the route
        assert response.json() == _approx(want)
        assert len(want["samples"]) > 1 and want["segments"]


def test_unknown_targets_are_404(client: TestClient, done: dict[str, Any]) -> None:
    for target in ("T0", "T999", "lorry"):
        problem = assert_problem(client.get(f"/v1/jobs/{done['job']['id']}/targets/{target}"), 404)
        assert "T1..T" in problem["detail"]


@pytest.mark.parametrize(
    ("path", "params", "field"),
    [
        ("plot", {"kind": "heatmap"}, "kind"),
        ("plot", {"format": "gif"}, "format"),
        ("positions", {}, "t"),
        ("positions", {"t": "nan"}, "t"),
        ("positions", {"t": "soon"}, "t"),
        ("targets/T1", {"step": 0}, "step"),
        ("targets/T1", {"step": "inf"}, "step"),
        ("targets/T1", {"step": 1e-9}, "step"),  # too many samples
        ("targets/T1", {"step": 5e-324}, "step"),  # span / step overflows (found by fuzzing)
    ],
)
def test_bad_parameters_are_422(
    client: TestClient, done: dict[str, Any], path: str, params: dict[str, Any], field: str
) -> None:
    problem = assert_problem(client.get(f"/v1/jobs/{done['job']['id']}/{path}", params=params), 422)
    assert [e["field"] for e in problem["errors"]] == [field]


ROUTES = ("plot", "plot?format=svg", "positions?t=10", "targets/T1")


def test_unfinished_and_unknown_jobs(
    client: TestClient, deployment: dict[str, Any], paper_csv: str
) -> None:
    queued = post_csv_batch(client, deployment["id"], paper_csv, associator=ASSOCIATOR)["job"]["id"]
    for route in ROUTES:
        problem = assert_problem(client.get(f"/v1/jobs/{queued}/{route}"), 409)
        assert "queued" in problem["detail"] and "wait" in problem["detail"]
        assert_problem(client.get(f"/v1/jobs/{uuid.uuid4()}/{route}"), 404)
    assert_problem(client.get("/v1/jobs/not-a-job/plot"), 422)
    cancelled = client.post(f"/v1/jobs/{queued}/cancel")
    assert cancelled.json()["state"] == "cancelled"
    problem = assert_problem(client.get(f"/v1/jobs/{queued}/plot"), 409)
    assert "cancelled" in problem["detail"]


def test_keys_and_scopes(
    client: TestClient, done: dict[str, Any], make_key: MakeKey, deployment: dict[str, Any]
) -> None:
    anonymous = TestClient(client.app)
    job = done["job"]["id"]
    other = client.post("/v1/deployments", json={"name": "elsewhere"}).json()["id"]
    read, own, foreign = (
        bearer(make_key("read")),
        bearer(make_key("ingest", deployment["id"])),
        bearer(make_key("ingest", other)),
    )
    for route in ROUTES:
        response = anonymous.get(f"/v1/jobs/{job}/{route}")
        assert_problem(response, 401)
        assert response.headers["www-authenticate"].startswith("Bearer")
        assert_problem(anonymous.get(f"/v1/jobs/{job}/{route}", headers=foreign), 403)
        for allowed in (read, own):
            assert anonymous.get(f"/v1/jobs/{job}/{route}", headers=allowed).status_code == 200


def _approx(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _approx(v) for k, v in value.items()}
    if isinstance(value, list):
        return [_approx(v) for v in value]
    if isinstance(value, float):
        return pytest.approx(value, rel=1e-12, abs=1e-9)
    return value


def test_the_route_names_follow_the_contract(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    ids = {
        op["operationId"]
        for path, ops in spec["paths"].items()
        if re.match(r"/v1/jobs/\{job_id\}/(plot|positions|targets|page-link)", path)
        for op in ops.values()
    }
    assert ids == {
        "jobs-get_plot",
        "jobs-get_positions",
        "jobs-get_target",
        "jobs-create_page_link",
    }
