"""Prometheus metrics: requests counted by the API; job figures read from the queue table, and
the workers' liveness from their heartbeat rows, so they are right however many API replicas
and workers there are, on whichever hosts."""

from __future__ import annotations

import time
from collections.abc import Iterator

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, HistogramMetricFamily, Metric
from prometheus_client.registry import Collector
from sqlalchemy.orm import Session, sessionmaker
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from roadlink.db.repository import count_jobs_by_state, job_duration_histogram
from roadlink.db.worker_heartbeats import heartbeats

JOB_DURATION_BUCKETS = (0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 5.0, 10.0, 30.0, 60.0, 300.0)


class QueueCollector(Collector):
    """Jobs by state, queue depth, job durations and the workers' heartbeats, queried at scrape
    time. A worker is live when it beat within `lease_seconds` (as for `roadlink worker
    --check`: one silent for a lease has lost its job's lease too)."""

    def __init__(self, sessions: sessionmaker[Session], lease_seconds: float) -> None:
        self.sessions = sessions
        self.lease_seconds = lease_seconds

    def collect(self) -> Iterator[Metric]:
        with self.sessions() as session:
            by_state = count_jobs_by_state(session)
            cumulative, count, total = job_duration_histogram(session, buckets=JOB_DURATION_BUCKETS)
            workers = heartbeats(session)
        yield GaugeMetricFamily(
            "roadlink_workers_live",
            "Worker processes, on any host, that beat within a lease (ROADLINK_LEASE_SECONDS).",
            value=sum(w.age_seconds <= self.lease_seconds for w in workers),
        )
        ages = GaugeMetricFamily(
            "roadlink_worker_heartbeat_age_seconds",
            "Seconds since each worker process last beat (a stopped worker is removed; a "
            "killed one ages until it is forgotten an hour later).",
            labels=["worker", "host"],
        )
        for worker in workers:
            ages.add_metric([worker.worker_id, worker.host], worker.age_seconds)
        yield ages
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

    def __init__(self, sessions: sessionmaker[Session], *, lease_seconds: float) -> None:
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
        self.registry.register(QueueCollector(sessions, lease_seconds))


class RequestMetrics:
    """Counts and times every request, labelled by its route template (not its path, which
    would make a label per id), once its response starts (or as a 500 when none does).

    A plain ASGI middleware: as `@app.middleware("http")` (Starlette's BaseHTTPMiddleware) it
    cost every request a task and a stream of its own."""

    def __init__(self, app: ASGIApp, metrics: ApiMetrics) -> None:
        self.app = app
        self.metrics = metrics

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        counted = False

        def count(status: int) -> None:
            nonlocal counted
            counted = True
            method, route = scope["method"], _route_template(scope)
            self.metrics.requests.labels(method, route, str(status)).inc()
            self.metrics.latency.labels(method, route).observe(time.perf_counter() - started)

        async def send_counted(message: Message) -> None:
            if message["type"] == "http.response.start" and not counted:
                count(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, send_counted)
        finally:
            if not counted:
                count(500)


def _route_template(scope: Scope) -> str:
    # The router records the route it matched in the (shared) scope.
    route = scope.get("route")
    return str(getattr(route, "path_format", None) or "unmatched")
