"""A worker's background duties besides jobs, in a thread of their own so that a long job does
not hold them up: sending due webhook deliveries, and applying ROADLINK_RETENTION_DAYS."""

from __future__ import annotations

import logging
import threading
import time

from sqlalchemy.orm import Session, sessionmaker

from roadlink.queue.retention import delete_expired
from roadlink.queue.webhook_dispatch import WebhookDispatcher
from roadlink.settings import Settings

log = logging.getLogger(__name__)

# How often the thread looks for due deliveries (a read; nothing is written when none is due).
POLL_SECONDS = 1.0

# How often retention runs in each worker (the first time as the worker starts).
RETENTION_EVERY_SECONDS = 3600.0


class Housekeeping:
    """Runs until `stopping` is set: deliveries every POLL_SECONDS, retention hourly."""

    def __init__(
        self, settings: Settings, sessions: sessionmaker[Session], stopping: threading.Event
    ) -> None:
        self.settings = settings
        self.sessions = sessions
        self.stopping = stopping
        self.dispatcher = WebhookDispatcher(settings, sessions)
        self._last_retention: float | None = None
        self.thread = threading.Thread(target=self._run, name="housekeeping", daemon=True)

    def start(self) -> None:
        self.thread.start()

    def join(self, timeout: float) -> None:
        self.thread.join(timeout)
        self.dispatcher.close()

    def _run(self) -> None:
        while not self.stopping.is_set():
            try:
                self.dispatcher.dispatch_due()
                self._retention_when_due()
            except Exception:  # a transient database error: the next round tries again
                log.exception("housekeeping failed; trying again")
            self.stopping.wait(POLL_SECONDS)

    def _retention_when_due(self) -> None:
        days = self.settings.retention_days
        now = time.monotonic()
        if days is None or (
            self._last_retention is not None
            and now - self._last_retention < RETENTION_EVERY_SECONDS
        ):
            return
        self._last_retention = now
        delete_expired(self.sessions, days=days)
