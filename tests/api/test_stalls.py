"""The API's watches on its event loop and its garbage collections (roadlink/api/stalls.py)."""

from __future__ import annotations

import asyncio
import gc
import logging
import re
import time

import pytest
from fastapi.testclient import TestClient
from prometheus_client import CollectorRegistry
from sqlalchemy import Engine

from roadlink.api import create_app
from roadlink.api.stalls import Clocks, StallWatch
from roadlink.settings import Settings

BLOCK_CPU_SECONDS = 0.2


def _metric(text: str, name: str) -> float:
    return sum(float(line.rsplit(" ", 1)[1]) for line in text.splitlines() if line.startswith(name))


def test_the_app_times_collections_and_its_loop_while_it_runs(client: TestClient) -> None:
    stalls = client.app.state.stalls  # type: ignore[attr-defined]
    assert stalls.on_gc in gc.callbacks
    gc.collect()
    text = client.get("/metrics").text
    assert _metric(text, 'roadlink_gc_pause_seconds_count{generation="2"}') >= 1
    assert "roadlink_event_loop_lag_seconds_count" in text


def test_the_watches_stop_with_the_app(settings: Settings, engine: Engine) -> None:
    app = create_app(settings, engine=engine)
    with TestClient(app):
        assert app.state.stalls.on_gc in gc.callbacks
    assert app.state.stalls.on_gc not in gc.callbacks


def test_a_long_collection_is_logged(caplog: pytest.LogCaptureFixture) -> None:
    watch = StallWatch(CollectorRegistry(), log_seconds=1e-9)
    gc.callbacks.append(watch.on_gc)
    try:
        with caplog.at_level(logging.WARNING, logger="roadlink.stalls"):
            gc.collect()
    finally:
        gc.callbacks.remove(watch.on_gc)
    assert watch.gc_seconds > 0
    assert any("garbage collection of generation 2" in r.message for r in caplog.records)


def _busy_on_this_thread(cpu_seconds: float) -> None:
    began = time.thread_time()
    while time.thread_time() - began < cpu_seconds:
        pass


async def _block_the_loop(watch: StallWatch) -> None:
    """Keep the loop's thread busy while the watch runs, until it has observed that."""
    seen = asyncio.Event()
    observe = watch.observe_lag

    def observed(late: float, span: float, spent: Clocks) -> None:
        observe(late, span, spent)
        if late >= BLOCK_CPU_SECONDS / 2:
            seen.set()

    watch.observe_lag = observed  # type: ignore[method-assign]
    async with watch.running():
        await asyncio.sleep(0)  # a turn of the loop, in which the watch takes its first reading
        _busy_on_this_thread(BLOCK_CPU_SECONDS)
        await asyncio.wait_for(seen.wait(), timeout=60)


def test_a_busy_loop_is_logged_as_late_with_its_thread_on_a_core(
    caplog: pytest.LogCaptureFixture,
) -> None:
    watch = StallWatch(CollectorRegistry(), log_seconds=BLOCK_CPU_SECONDS / 2)
    with caplog.at_level(logging.WARNING, logger="roadlink.stalls"):
        asyncio.run(_block_the_loop(watch))
    late = [r.message for r in caplog.records if r.message.startswith("event loop")]
    on_core = [int(re.findall(r"loop thread on a core (\d+) ms", m)[0]) for m in late]
    assert max(on_core) >= BLOCK_CPU_SECONDS * 1000 * 0.9, late
