"""The long-poll wait for a job: until it finishes, the wait runs out, or the client goes away
(`roadlink.services.waiting`)."""

from __future__ import annotations

import asyncio
import time
import uuid
from collections.abc import Awaitable, Callable
from types import SimpleNamespace
from typing import Any

import pytest

from roadlink.db.models import JobState
from roadlink.services import waiting
from roadlink.services.problems import ServiceProblem
from roadlink.services.waiting import wait_for_job


class Finishes:
    """Stands in for `FinishedJobs`: hands out events, and sets them when told."""

    listening = True
    rung = True

    def __init__(self) -> None:
        self.events: dict[uuid.UUID, asyncio.Event] = {}

    def watch(self, job_id: uuid.UUID) -> asyncio.Event:
        self.events[job_id] = asyncio.Event()
        return self.events[job_id]

    def unwatch(self, job_id: uuid.UUID, event: asyncio.Event) -> None:
        assert self.events.pop(job_id) is event


def _reader(states: list[JobState]) -> Callable[[], Awaitable[Any]]:
    """Reads the job in each state in turn, then in the last for ever; counts the reads."""

    async def read_job() -> Any:
        state = states.pop(0) if len(states) > 1 else states[0]
        return SimpleNamespace(state=state)

    return read_job


async def _present() -> bool:
    return False


def _wait(read_job: Callable[[], Awaitable[Any]], wait: float, **kwargs: Any) -> Any:
    kwargs = {"max_wait": 10.0, "finished_jobs": None, "client_gone": _present, **kwargs}
    return asyncio.run(wait_for_job(uuid.uuid4(), wait=wait, read_job=read_job, **kwargs))


def test_a_finished_job_is_answered_at_once() -> None:
    started = time.monotonic()
    assert _wait(_reader([JobState.SUCCEEDED]), 5.0).state is JobState.SUCCEEDED
    assert time.monotonic() - started < 1.0


def test_an_unfinished_job_is_answered_as_it_stands_when_the_wait_runs_out() -> None:
    started = time.monotonic()
    assert _wait(_reader([JobState.RUNNING]), 0.3).state is JobState.RUNNING
    assert 0.3 <= time.monotonic() - started < 2.0


def test_the_wait_is_capped() -> None:
    started = time.monotonic()
    _wait(_reader([JobState.QUEUED]), 60.0, max_wait=0.2)
    assert time.monotonic() - started < 2.0


def test_a_job_that_finishes_meanwhile_is_answered_when_read_again() -> None:
    states = [JobState.QUEUED, JobState.RUNNING, JobState.SUCCEEDED]
    assert _wait(_reader(states), 5.0).state is JobState.SUCCEEDED


def test_a_missing_job_is_a_404_and_a_client_gone_a_408() -> None:
    async def nothing() -> None:
        return None

    async def gone() -> bool:
        return True

    with pytest.raises(ServiceProblem) as missing:
        _wait(nothing, 1.0)
    assert missing.value.status == 404
    with pytest.raises(ServiceProblem) as left:
        _wait(_reader([JobState.RUNNING]), 5.0, client_gone=gone)
    assert left.value.status == 408


def test_the_finish_notification_wakes_the_wait_before_its_next_read(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    monkeypatch.setattr(waiting, "WAIT_FIRST_POLL_SECONDS", 5.0)  # the next read, unless woken
    finishes = Finishes()
    reads: list[float] = []
    started = time.monotonic()

    async def read_job() -> Any:
        reads.append(time.monotonic() - started)
        if len(reads) == 1:  # the job finishes now; its news comes a moment later
            event = next(iter(finishes.events.values()))
            asyncio.get_running_loop().call_later(0.1, event.set)
        return SimpleNamespace(state=JobState.RUNNING if len(reads) == 1 else JobState.SUCCEEDED)

    assert _wait(read_job, 30.0, finished_jobs=finishes).state is JobState.SUCCEEDED
    assert len(reads) == 2 and reads[1] < 2.0, "woken by the news, not by the next poll"
    assert finishes.events == {}, "the waiter is given back"


@pytest.mark.parametrize("rung", [True, False], ids=["rung", "not-rung"])
def test_a_wait_that_rings_reach_reads_again_only_to_cover_a_lost_ring(
    monkeypatch: pytest.MonkeyPatch, rung: bool
) -> None:
    """SQLite's doorbell: a finish in another process rings, though a ring may be lost, so the
    job is read again at the slow pace only; without a doorbell, often at first."""
    monkeypatch.setattr(waiting, "WAIT_FIRST_POLL_SECONDS", 0.01)
    monkeypatch.setattr(waiting, "WAIT_RUNG_POLL_SECONDS", 0.5)
    finishes = Finishes()
    finishes.listening, finishes.rung = False, rung
    started = time.monotonic()
    states = [JobState.RUNNING, JobState.SUCCEEDED]  # finished, and its ring lost
    assert _wait(_reader(states), 30.0, finished_jobs=finishes).state is JobState.SUCCEEDED
    took = time.monotonic() - started
    assert took >= 0.5 if rung else took < 0.4
