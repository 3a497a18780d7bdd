"""A worker's housekeeping thread: retention when the worker starts and then hourly, only when
ROADLINK_RETENTION_DAYS is set (what it deletes: tests/queue/test_retention.py; the deliveries
it sends: tests/queue/test_webhook_dispatch.py)."""

from __future__ import annotations

import threading

import pytest
from sqlalchemy import Engine

from roadlink.db.engine import make_session_factory
from roadlink.queue import housekeeping
from roadlink.queue.housekeeping import Housekeeping
from roadlink.settings import Settings


def test_workers_apply_retention_when_they_start_and_then_hourly(
    settings: Settings, engine: Engine, monkeypatch: pytest.MonkeyPatch
) -> None:
    passes: list[float] = []
    monkeypatch.setattr(housekeeping, "delete_expired", lambda _s, days: passes.append(days))
    unset = Housekeeping(settings, make_session_factory(engine), threading.Event())
    unset._retention_when_due()
    assert passes == []
    kept = settings.model_copy(update={"retention_days": 30.0})
    chores = Housekeeping(kept, make_session_factory(engine), threading.Event())
    chores._retention_when_due()
    chores._retention_when_due()  # within the hour: not again
    assert passes == [30.0]
    chores._last_retention -= housekeeping.RETENTION_EVERY_SECONDS  # type: ignore[operator]
    chores._retention_when_due()
    assert passes == [30.0, 30.0]
    unset.dispatcher.close()
    chores.dispatcher.close()
