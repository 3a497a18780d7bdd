"""A succeeded job's result for the routes that draw or localise it (`api/jobresults.py`): one
rebuild per job, kept within a budget of detections; plots drawn once, in a process of their own
at the workers' priority; and the refusals (404, 409, 413) every view of a result goes through."""

from __future__ import annotations

import os
import uuid
from typing import Any

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine

from roadlink.api import create_app, jobresults
from roadlink.api.errors import ApiProblem
from roadlink.api.jobresults import (
    CachedResult,
    JobResultCache,
    job_result,
    render_elsewhere,
    too_large_to_view,
    unfinished_detail,
)
from roadlink.association import associate
from roadlink.association.result import AssociationResult
from roadlink.db import repository
from roadlink.db.engine import make_session_factory
from roadlink.db.models import JobState
from roadlink.queue.worker import Worker
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.helpers import assert_problem, bearer, post_csv_batch, unsaved_job


@pytest.fixture(scope="module")
def local() -> AssociationResult:
    """A result of 100 detections, as the core computes it."""
    return associate(simulate(preset("large"), seed=5).detections, "kmeans++")


def test_the_cache_loads_a_job_once_and_keeps_within_its_budget(local: AssociationResult) -> None:
    cache = JobResultCache(max_detections=2 * len(local.detections))
    loads: list[int] = []

    def load() -> AssociationResult:
        loads.append(1)
        return local

    first, second, third = (uuid.uuid4() for _ in range(3))
    entry = cache.get(first, load)
    assert entry is cache.get(first, load) and len(loads) == 1
    assert entry is not None and entry.job_id == first and entry.result is local
    cache.get(second, load)
    cache.get(first, lambda: None)  # used again: the second is now the oldest
    cache.get(third, load)
    assert cache.get(second, lambda: None) is None  # dropped, and nothing to load
    assert cache.get(first, lambda: None) is not None


def test_the_most_recent_result_is_kept_whatever_its_size(local: AssociationResult) -> None:
    cache = JobResultCache(max_detections=1)
    older, newer = uuid.uuid4(), uuid.uuid4()
    cache.get(older, lambda: local)
    cache.get(newer, lambda: local)
    assert cache.get(newer, lambda: None) is not None
    assert cache.get(older, lambda: None) is None


def test_a_plot_is_rendered_once_per_kind_and_format(
    local: AssociationResult, monkeypatch: pytest.MonkeyPatch
) -> None:
    drawn: list[tuple[str, str]] = []

    def render(result: AssociationResult, kind: str, fmt: str) -> bytes:
        drawn.append((kind, fmt))
        return f"{kind}.{fmt}".encode()

    monkeypatch.setattr(jobresults, "render_elsewhere", render)
    cached = CachedResult(uuid.uuid4(), local)
    assert cached.plot("time-space", "svg") == b"time-space.svg"
    assert cached.plot("time-space", "svg") == b"time-space.svg"
    assert cached.plot("time-space", "png") == b"time-space.png"
    assert drawn == [("time-space", "svg"), ("time-space", "png")]
    assert cached.trajectories is cached.trajectories  # localised once
    assert [t.target for t in cached.trajectories] == [f"T{k + 1}" for k in range(local.n_targets)]


def test_plots_are_drawn_at_a_lower_priority(local: AssociationResult) -> None:
    """Drawing, the API's heaviest work, must not take a core from its event loop."""
    assert render_elsewhere(local, "time-space", "svg").startswith(b"<?xml")
    assert jobresults._renderer is not None
    niceness = jobresults._renderer.submit(os.nice, 0).result()
    assert niceness == min(os.nice(0) + jobresults.RENDERER_NICENESS, 19)


def test_why_a_job_has_no_result() -> None:
    failed = unsaved_job(state=JobState.FAILED, error="the associator ran out of time")
    assert unfinished_detail(failed) == (
        f"job {failed.id} failed, so it has no result: the associator ran out of time"
    )
    cancelled = unsaved_job(state=JobState.CANCELLED)
    assert unfinished_detail(cancelled) == f"job {cancelled.id} was cancelled, so it has no result"
    running = unsaved_job(state=JobState.RUNNING, progress=0.42)
    detail = unfinished_detail(running)
    assert detail.startswith(f"job {running.id} is running (42% done)") and "?wait=" in detail


def test_too_large_to_view_points_to_the_whole_result() -> None:
    job_id = uuid.uuid4()
    problem = too_large_to_view(job_id, 1_000_000, 20_000)
    assert problem.status == 413
    assert "1000000 detections" in problem.detail and "at most 20000" in problem.detail
    assert f"GET /v1/jobs/{job_id}/result" in problem.detail


def _post_and_run(
    client: TestClient, worker: Worker | None, deployment: dict[str, Any], paper_csv: str
) -> str:
    """A job over the paper batch (100 detections), run when a worker is given; its id."""
    batch = post_csv_batch(client, deployment["id"], paper_csv, associator="kmeans")
    if worker is not None:
        assert worker.run_once()
    return str(batch["job"]["id"])


def test_a_job_result_is_refused_when_unknown_unfinished_or_too_large(
    client: TestClient, engine: Engine, deployment: dict[str, Any], paper_csv: str
) -> None:
    job_id = uuid.UUID(
        _post_and_run(client, None, deployment, paper_csv)
    )  # no worker: it stays queued
    with make_session_factory(engine)() as session:
        with pytest.raises(ApiProblem) as unknown:
            job_result(session, JobResultCache(), uuid.uuid4(), 1000)
        assert unknown.value.status == 404
        with pytest.raises(ApiProblem) as queued:
            job_result(session, JobResultCache(), job_id, 1000)
        assert queued.value.status == 409 and "queued" in queued.value.detail


def test_a_succeeded_job_result_is_read_once_and_served_from_the_cache(
    client: TestClient,
    worker: Worker,
    engine: Engine,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    job_id = uuid.UUID(_post_and_run(client, worker, deployment, paper_csv))
    cache = JobResultCache()
    with make_session_factory(engine)() as session:
        entry = job_result(session, cache, job_id, 1000)
        assert len(entry.result.detections) == 100 and entry.result.associator == "kmeans"
        assert job_result(session, cache, job_id, 1000) is entry
        with pytest.raises(ApiProblem) as large:
            job_result(session, JobResultCache(), job_id, 99)
        assert large.value.status == 413


def test_every_view_of_a_result_past_the_limit_is_refused_before_it_is_read(
    settings: Settings,
    engine: Engine,
    admin_key: str,
    client: TestClient,
    worker: Worker,
    deployment: dict[str, Any],
    paper_csv: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Drawing or localising a million detections took the API minutes of CPU and gigabytes; past
    ROADLINK_MAX_VIEW_DETECTIONS the views say so at once, without reading the result."""
    job = _post_and_run(client, worker, deployment, paper_csv)  # 100 detections

    def never(*_args: object, **_kwargs: object) -> None:
        raise AssertionError("the result was read")

    monkeypatch.setattr(repository, "load_job_association", never)
    small = settings.model_copy(update={"max_view_detections": 99})
    with TestClient(create_app(small, engine=engine), headers=bearer(admin_key)) as http:
        for path, params in [
            ("plot", {}),
            ("plot", {"format": "svg", "kind": "backprojected"}),
            ("positions", {"t": 10}),
            ("targets/T1", {}),
        ]:
            problem = assert_problem(http.get(f"/v1/jobs/{job}/{path}", params=params), 413)
            assert "ROADLINK_MAX_VIEW_DETECTIONS" in problem["detail"]
            assert f"/v1/jobs/{job}/result" in problem["detail"]
        page = http.get(f"/jobs/{job}")
        assert page.status_code == 200 and 'id="too-large"' in page.text
        assert "100 detections" in page.text and 'id="plot"' not in page.text
        assert http.get(f"/v1/jobs/{job}/result").status_code == 200  # read whole, as stored


def test_a_plot_is_drawn_with_no_database_connection_held(
    client: TestClient,
    worker: Worker,
    engine: Engine,
    deployment: dict[str, Any],
    paper_csv: str,
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Drawing waits for the one renderer, seconds under load: a plot request that held its
    connection meanwhile let a burst of them take the whole pool (benchmarks/soak.py on a loaded
    machine: 503s), so the connection goes back before drawing, cached result or not."""
    job = _post_and_run(client, worker, deployment, paper_csv)
    held: list[int] = []

    def render(result: AssociationResult, kind: str, fmt: str) -> bytes:
        held.append(engine.pool.checkedout())  # type: ignore[attr-defined]
        return b"<svg/>"

    monkeypatch.setattr(jobresults, "render_elsewhere", render)
    for fmt in ("svg", "png"):  # the first reads the result, the second finds it cached
        assert client.get(f"/v1/jobs/{job}/plot", params={"format": fmt}).status_code == 200
    page = client.get(f"/jobs/{job}", params={"kind": "backprojected"})  # drawn for the page
    assert page.status_code == 200
    assert held == [0, 0, 0]
