"""A succeeded job's result as the core's `AssociationResult`, for every route that draws or
localises it (plot, positions, targets, the job page), rebuilt once per job and kept.

A succeeded job's result never changes, so what is derived from it (the result itself, the
targets' trajectories, the rendered plots) is computed on first use and cached in the API process,
least recently used first out, within a budget of detections.
"""

from __future__ import annotations

import multiprocessing
import os
import threading
import uuid
from collections import OrderedDict
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from functools import cached_property
from typing import Annotated, Any

from fastapi import Depends, Request
from sqlalchemy.orm import Session

from roadlink.api.deps import SessionDep, SettingsDep
from roadlink.api.errors import ApiProblem
from roadlink.association.localisation import Trajectory, target_trajectories
from roadlink.association.result import AssociationResult
from roadlink.db import repository
from roadlink.db.models import Job, JobState
from roadlink.plots import render_plot

CACHE_DETECTIONS = 20_000
"""Detections the cache may hold across jobs (a few hundred bytes each, with their trajectories);
the most recent result is kept whatever its size. Everything cached is walked by each full
garbage collection, which stops every request meanwhile, so the budget is kept to what the few
jobs that people look at need. Each cached detection is an object the collector walks (its
trajectory's `SensorPass`): at 100,000 (a thousand jobs of 100 detections, as benchmarks/soak.py
fills it) a full collection took 43 ms of CPU on an idle core and 40-215 ms under the soak's
load, which /healthz answers waited for; at 20,000, 5 ms on an idle core."""


class CachedResult:
    """One succeeded job's result, and what is derived from it, each computed once."""

    def __init__(self, job_id: uuid.UUID, result: AssociationResult) -> None:
        self.job_id = job_id
        self.result = result
        self._plots: dict[tuple[str, str], bytes] = {}
        self._plots_lock = threading.Lock()

    @cached_property
    def trajectories(self) -> list[Trajectory]:
        """Every target's trajectory, in target order (T1 first)."""
        return target_trajectories(self.result)

    @cached_property
    def vehicle_features(self) -> list[dict[str, Any]]:
        """Every target's `length` and `vehicle_class` as the result gives them, in target
        order; empty dicts when the detections report neither."""
        features = self.result.detections.features
        return [
            self.result.target_features(members, features)
            for members in self.result.target_members()
        ]

    def plot(self, kind: str, fmt: str) -> bytes:
        """The plot of the result (see `roadlink.plots.render_plot`), rendered once per kind and
        format."""
        key = (kind, fmt)
        with self._plots_lock:
            cached = self._plots.get(key)
        if cached is not None:
            return cached
        # Rendered outside the lock: two first requests may both render, which is harmless and
        # keeps a slow plot from blocking the other kinds.
        image = render_elsewhere(self.result, kind, fmt)
        with self._plots_lock:
            return self._plots.setdefault(key, image)


# How much lower than the API's the plot renderer's priority is: drawing is the API's own
# background work, and its event loop must not wait for a core behind it.
RENDERER_NICENESS = 10

_renderer: ProcessPoolExecutor | None = None
_renderer_lock = threading.Lock()


def render_elsewhere(result: AssociationResult, kind: str, fmt: str) -> bytes:
    """`render_plot` in a process of its own, one per API process, started at the first plot.

    Drawing holds the GIL in matplotlib's C++ for a quarter of a second and more at a time; in
    the API process that stalls the event loop, so /healthz and every other request wait behind
    a plot. Measured with benchmarks/soak.py (16 clients): /healthz p99 225 ms with plots drawn
    in the API process.

    The renderer runs at a lower priority (`RENDERER_NICENESS`): drawing is the API process
    tree's biggest use of CPU (a third of two cores in the soak), and at the API's own priority
    it kept the event loop waiting for a core for up to 100 ms at a time.
    """
    global _renderer
    with _renderer_lock:
        if _renderer is None:
            _renderer = ProcessPoolExecutor(
                max_workers=1,
                mp_context=multiprocessing.get_context("spawn"),
                initializer=os.nice,
                initargs=(RENDERER_NICENESS,),
            )
        renderer = _renderer
    return renderer.submit(render_plot, result, kind, fmt).result()


class JobResultCache:
    """Succeeded jobs' results by job id, least recently used first out."""

    def __init__(self, max_detections: int = CACHE_DETECTIONS) -> None:
        self.max_detections = max_detections
        self._entries: OrderedDict[uuid.UUID, CachedResult] = OrderedDict()
        self._lock = threading.Lock()

    def get(
        self, job_id: uuid.UUID, load: Callable[[], AssociationResult | None]
    ) -> CachedResult | None:
        """The cached result of `job_id`, or `load()`'s (cached when not None)."""
        with self._lock:
            entry = self._entries.get(job_id)
            if entry is not None:
                self._entries.move_to_end(job_id)
                return entry
        result = load()
        if result is None:
            return None
        with self._lock:
            entry = self._entries.setdefault(job_id, CachedResult(job_id, result))
            self._entries.move_to_end(job_id)
            held = sum(len(e.result.detections) for e in self._entries.values())
            while held > self.max_detections and len(self._entries) > 1:
                _, dropped = self._entries.popitem(last=False)
                held -= len(dropped.result.detections)
            return entry


def job_result(
    session: Session, cache: JobResultCache, job_id: uuid.UUID, max_detections: int
) -> CachedResult:
    """The result of a succeeded job; 404 for an unknown job, 409 for an unfinished one, 413
    for one of more than `max_detections` detections.

    The session's connection goes back to the pool before this returns.

    Every view of a result (plot, positions, targets, the job page) reads it here, so this is
    the one bound on what a read of a result may cost the API: rebuilding, drawing or
    localising a million detections takes minutes of CPU and gigabytes, which no request may
    start. Such results are read whole, as stored, from the result route.
    """

    def load() -> AssociationResult | None:
        job = repository.get_job(session, job_id=job_id)
        if job is None:
            raise ApiProblem(404, f"there is no job {job_id}")
        if job.state != JobState.SUCCEEDED:
            raise ApiProblem(409, unfinished_detail(job))
        if job.n_detections is not None and job.n_detections > max_detections:
            raise too_large_to_view(job.id, job.n_detections, max_detections)
        return repository.load_job_association(session, job=job)

    entry = cache.get(job_id, load)
    # What the caller does next (drawing, waiting for the one renderer, localising) takes
    # seconds under load; holding the connection meanwhile let a burst of plot requests take
    # every connection of the pool, and the other routes answered 503. Nothing read here is
    # used lazily, and the session opens a new transaction if the caller reads again.
    session.close()
    if entry is None:  # succeeded without a result cannot happen: both commit together
        raise ApiProblem(500, f"job {job_id} succeeded but its result is missing")
    return entry


def too_large_to_view(job_id: uuid.UUID, n_detections: int, limit: int) -> ApiProblem:
    """The refusal to draw or localise a result past the limit."""
    return ApiProblem(
        413,
        f"job {job_id} has {n_detections} detections; plots, positions, targets and the job "
        f"page are made for at most {limit} (ROADLINK_MAX_VIEW_DETECTIONS): read its result "
        f"from GET /v1/jobs/{job_id}/result (JSON, or ?format=csv)",
    )


def unfinished_detail(job: Job) -> str:
    """Why a job has no result (yet), for a 409."""
    if job.state == JobState.FAILED:
        return f"job {job.id} failed, so it has no result: {job.error}"
    if job.state == JobState.CANCELLED:
        return f"job {job.id} was cancelled, so it has no result"
    return (
        f"job {job.id} is {job.state} ({job.progress:.0%} done); ask again later, "
        "or add ?wait=SECONDS to wait for it"
    )


def get_job_result_cache(request: Request) -> JobResultCache:
    """The app's cache of succeeded jobs' results."""
    cache: JobResultCache = request.app.state.job_results
    return cache


def get_succeeded_job_result(
    job_id: uuid.UUID,
    session: SessionDep,
    settings: SettingsDep,
    cache: Annotated[JobResultCache, Depends(get_job_result_cache)],
) -> CachedResult:
    """The `job_id` path parameter's result (404 / 409 / 413 as `job_result`)."""
    return job_result(session, cache, job_id, settings.max_view_detections)


SucceededJobDep = Annotated[CachedResult, Depends(get_succeeded_job_result)]
