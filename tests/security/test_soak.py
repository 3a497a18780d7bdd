"""The soak of benchmarks/soak.py, shortened for the suite: 16 clients mix idempotent retries sent
at once, jobs, `?wait=` and result reads (plots and positions included) against a live server,
while a probe in another process requests /healthz."""

from __future__ import annotations

import pytest

from benchmarks.soak import run_soak

pytestmark = pytest.mark.slow

CLIENTS = 16
SECONDS = 45.0
# The benchmark's goal is 100 ms (docs/security.md has its figures); the suite runs on machines
# that CI may share, so here the bound only catches an API that stalls (as it did for 230 ms at a
# time while drawing plots, and for 30 s when waiters took the database pool).
HEALTHZ_BOUND_MS = 1000.0


def test_sixteen_clients_get_no_5xx_and_the_api_keeps_answering() -> None:
    figures = run_soak(CLIENTS, SECONDS, wait=10.0)
    assert figures["failure_count"] == 0, figures["failures"]
    statuses = figures["statuses"]
    assert isinstance(statuses, dict)
    for what in ("batch csv", "batch json", "job", "result wait", "plot", "positions", "healthz"):
        assert any(name.startswith(what) for name in statuses), (what, statuses)
    assert figures["healthz_max_ms"] < HEALTHZ_BOUND_MS, figures
