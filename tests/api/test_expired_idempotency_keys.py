"""The task that forgets expired Idempotency-Keys (`api/expired_idempotency_keys.py`): it asks
the service with the app's sessions and settings, logs what it forgot, survives a failing round,
and stops with the app. (Which keys expire is the service's rule: tests/services.)"""

from __future__ import annotations

import asyncio
import logging
from types import SimpleNamespace

import pytest

from roadlink.api import expired_idempotency_keys
from roadlink.api.expired_idempotency_keys import forgetting_expired_keys
from roadlink.db.idempotency_records import Forgotten


def test_each_round_forgets_logs_and_survives_a_failure(
    monkeypatch: pytest.MonkeyPatch, caplog: pytest.LogCaptureFixture
) -> None:
    app = SimpleNamespace(state=SimpleNamespace(sessions=object(), settings=object()))
    answers: list[Forgotten | Exception] = [RuntimeError("database is locked"), Forgotten(2, 1)]
    asked: list[tuple[object, object]] = []

    async def main() -> None:
        loop = asyncio.get_running_loop()
        answered = asyncio.Event()

        def forget(sessions: object, settings: object) -> Forgotten:
            """The service, in the task's worker thread: one answer a round. The round after
            the last answer starts once the task has logged it (signalled during the last
            answer's own round, the test could stop the task before it logged: flaky on a
            loaded machine)."""
            asked.append((sessions, settings))
            if not answers:
                loop.call_soon_threadsafe(answered.set)
                return Forgotten(0, 0)
            answer = answers.pop(0)
            if isinstance(answer, Exception):
                raise answer
            return answer

        monkeypatch.setattr(expired_idempotency_keys, "forget_expired_keys", forget)
        async with forgetting_expired_keys(app):  # type: ignore[arg-type]
            await asyncio.wait_for(answered.wait(), timeout=30)

    monkeypatch.setattr(expired_idempotency_keys, "FORGET_EVERY_SECONDS", 0.0)
    with caplog.at_level(logging.INFO, logger="roadlink"):
        asyncio.run(main())
    assert asked[0] == (app.state.sessions, app.state.settings)
    messages = [r.getMessage() for r in caplog.records]
    assert "could not forget expired Idempotency-Keys" in messages
    assert "forgot the Idempotency-Keys of 2 batch(es) and 1 job(s)" in messages
