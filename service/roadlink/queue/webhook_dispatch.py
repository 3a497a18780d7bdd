"""Sending the webhook outbox: each worker process claims due deliveries, POSTs each, signed,
with httpx, and records the answer; a failed attempt is tried again after an exponential
backoff (`queue/webhooks.py`). Never on a request's path: the API only writes outbox rows."""

from __future__ import annotations

import logging
from collections.abc import Callable
from datetime import UTC, datetime

import httpx
from sqlalchemy.orm import Session, sessionmaker

from roadlink import __version__
from roadlink.db.engine import transaction
from roadlink.logs import log_context
from roadlink.queue.webhook_signature import SIGNATURE_HEADER, signature
from roadlink.queue.webhooks import (
    Backoff,
    DueDelivery,
    claim_due_delivery,
    has_due_delivery,
    record_attempt,
)
from roadlink.settings import Settings

log = logging.getLogger(__name__)

# Most deliveries one call of `dispatch_due` sends, so that a long backlog does not starve the
# rest of the housekeeping (retention) of the thread that runs both.
DISPATCH_BATCH = 50

# What of a receiver's error answer the delivery log keeps.
MAX_ERROR_CHARS = 500


class WebhookDispatcher:
    """Sends due deliveries. `clock` (tests) replaces the database's clock, for the due times
    and the signature's timestamp alike, so that backoff can be driven without waiting."""

    def __init__(
        self,
        settings: Settings,
        sessions: sessionmaker[Session],
        *,
        clock: Callable[[], datetime] | None = None,
        client: httpx.Client | None = None,
    ) -> None:
        self.sessions = sessions
        self.clock = clock
        self.backoff = Backoff(
            settings.webhook_max_attempts,
            settings.webhook_backoff_seconds,
            settings.webhook_max_backoff_seconds,
        )
        # Past the send's timeout (connect, write, read, each), so a claim outlives its attempt.
        self.claim_seconds = 4 * settings.webhook_timeout_seconds + 30
        # Redirects are not followed: a webhook is registered with its final URL.
        self.client = client or httpx.Client(
            timeout=settings.webhook_timeout_seconds,
            follow_redirects=False,
            headers={"User-Agent": f"roadlink-webhooks/{__version__}"},
        )

    def close(self) -> None:
        self.client.close()

    def dispatch_due(self) -> int:
        """Send the deliveries due now (at most DISPATCH_BATCH); how many were attempted."""
        sent = 0
        while sent < DISPATCH_BATCH and self.dispatch_once():
            sent += 1
        return sent

    def dispatch_once(self) -> bool:
        """Claim one due delivery and attempt it; False when none was due."""
        with self.sessions() as session:
            if not has_due_delivery(session, now=self._now()):
                return False
        with transaction(self.sessions) as session:
            delivery = claim_due_delivery(
                session, claim_seconds=self.claim_seconds, now=self._now()
            )
        if delivery is None:
            return False
        with log_context(**delivery.context):
            status_code, error = self._send(delivery)
            with transaction(self.sessions) as session:
                state = record_attempt(
                    session,
                    delivery=delivery,
                    status_code=status_code,
                    error=error,
                    backoff=self.backoff,
                    now=self._now(),
                )
            log.info(
                "webhook delivery %s (event %s, attempt %d) to %s: %s -> %s",
                delivery.id,
                delivery.event_id,
                delivery.attempt,
                delivery.url,
                status_code if error is None else error,
                state,
            )
        return True

    def _now(self) -> datetime | None:
        return None if self.clock is None else self.clock()

    def _send(self, delivery: DueDelivery) -> tuple[int | None, str | None]:
        body = delivery.payload.encode()
        moment = self.clock() if self.clock is not None else datetime.now(UTC)
        headers = {
            "Content-Type": "application/json",
            SIGNATURE_HEADER: signature(delivery.secret, int(moment.timestamp()), body),
            "Roadlink-Event-Id": str(delivery.event_id),
            "Roadlink-Event-Type": delivery.event_type,
            "Roadlink-Delivery-Id": str(delivery.id),
            "Roadlink-Delivery-Attempt": str(delivery.attempt),
        }
        try:
            response = self.client.post(delivery.url, content=body, headers=headers)
        except httpx.HTTPError as exc:
            return None, f"{type(exc).__name__}: {exc}"[:MAX_ERROR_CHARS]
        if response.is_success:
            return response.status_code, None
        return response.status_code, f"HTTP {response.status_code}: {response.text}"[
            :MAX_ERROR_CHARS
        ]
