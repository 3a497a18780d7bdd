"""The child process that runs the core for a worker: its time limit."""

from __future__ import annotations

import time

import pytest

from roadlink.queue.associator_process import AssociatorProcess, Succeeded, TimedOut
from roadlink.simulation import preset, simulate

pytestmark = pytest.mark.usefixtures("test_associators")

# Longer than the job below takes once the child is up, shorter than the start made slow here.
TIME_LIMIT = 2.0
SLOW_START_SECONDS = 3.0


@pytest.mark.slow
def test_the_time_limit_counts_the_association_not_the_child_start(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """On a loaded machine a cold start of the child takes seconds; a job must not fail its
    time limit for that (it once did, with a 0.5 s limit)."""
    child = AssociatorProcess()
    ready = child._ready

    def slow_ready():  # type: ignore[no-untyped-def]
        time.sleep(SLOW_START_SECONDS)  # a cold start on a busy machine, not synchronisation
        return ready()

    monkeypatch.setattr(child, "_ready", slow_ready)
    detections = simulate(preset("small"), seed=1).detections
    try:
        outcome = child.run(
            detections,
            "kmeans++",
            {},
            time_limit=TIME_LIMIT,
            should_stop=lambda: False,
            on_progress=lambda _share: None,
        )
        assert isinstance(outcome, Succeeded), outcome
        spinning = child.run(
            detections,
            "test-sleeping",
            {"seconds": 30.0},
            time_limit=TIME_LIMIT,
            should_stop=lambda: False,
            on_progress=lambda _share: None,
        )
        assert isinstance(spinning, TimedOut)  # and the limit still holds
    finally:
        child.close()
