"""Prometheus metrics: requests counted by the API; job figures read from the queue table, so
they are right however many API replicas and workers there are."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Iterator

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from sqlalchemy.orm import Session, sessionmaker
from starlette.requests import Request
from starlette.responses import Response

from roadlink.db.repository import count_jobs_by_state, job_duration_histogram

JOB_DURATION_BUCKETS = (0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0)


class QueueCollector(Collector):
    """Jobs by state, queue depth and job durations, queried at scrape time."""

    def __init__(self, sessions: sessionmaker[Session]) -> None:
        self.sessions = sessions

    def collect(self) -> Iterator[Metric]:
        with self.sessions() as session:
            by_state = count_jobs_by_state(session)
            cumulative, count, total = job_duration_histogram(session, buckets=JOB_DURATION_BUCKETS)
        jobs = GaugeMetricFamily("roadlink_jobs", "Jobs by state.", labels=["state"])
        for state, n in by_state.items():
            jobs.add_metric([state], n)
        yield jobs
        yield GaugeMetricFamily(
            "roadlink_queue_depth", "Jobs queued and not yet claimed.", value=by_state["queued"]
        )
        buckets = [(repr(b), c) for b, c in zip(JOB_DURATION_BUCKETS, cumulative, strict=True)]
        buckets.append(("+Inf", count))
        yield HistogramMetricFamily(
            "roadlink_job_duration_seconds",
            "Run time of succeeded jobs.",
            buckets=buckets,
            sum_value=total,
        )


class ApiMetrics:
    """The registry of one app, with its request metrics."""

    def __init__(self, sessions: sessionmaker[Session]) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter(
            "roadlink_http_requests",
            "HTTP requests answered.",
            ["method", "route", "status"],
            registry=self.registry,
        )
        self.latency = Histogram(
            "roadlink_http_request_duration_seconds",
            "Time to answer HTTP requests.",
            ["method", "route"],
            registry=self.registry,
        )
        self.registry.register(QueueCollector(sessions))

    async def middleware(
        self, request: Request, call_next: Callable[[Request], Awaitable[Response]]
    ) -> Response:
        """Count and time every request, labelled by its route template (not its path, which
        would make a label per id)."""
        started = time.perf_counter()
        status = 500
        try:
            response = await call_next(request)
            status = response.status_code
            return response
        finally:
            route = _route_template(request)
            self.requests.labels(request.method, route, str(status)).inc()
            self.latency.labels(request.method, route).observe(time.perf_counter() - started)


def _route_template(request: Request) -> str:
    # The router records the route it matched in the (shared) scope.
    route = request.scope.get("route")
    return str(getattr(route, "path_format", None) or "unmatched")
