"""A per-key rate limit: one token bucket per API key, held in this process.

Each bucket holds up to `burst` tokens and refills at `rate` tokens per second; a request takes
one token, or is refused with the time until the next token (the 429's Retry-After). The buckets
live in the API process, so the limit holds per API replica: N replicas behind a load balancer
let a key through at up to N times the rate. That bounds what one misbehaving gateway can cost a
replica, which is the point; a global limit would need shared state (the database or Redis) on
every request.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

# Buckets idle this long are full again, so they can be dropped to bound memory.
IDLE_BUCKETS_CHECK_EVERY = 1024


@dataclass
class _Bucket:
    tokens: float
    updated: float


class TokenBuckets:
    """Token buckets keyed by API key (thread-safe: sync handlers run in a thread pool)."""

    def __init__(
        self, rate: float, burst: int, clock: Callable[[], float] = time.monotonic
    ) -> None:
        if rate <= 0 or burst < 1:
            raise ValueError("a token bucket needs rate > 0 and burst >= 1")
        self.rate = rate
        self.burst = burst
        self._clock = clock
        self._buckets: dict[str, _Bucket] = {}
        self._lock = threading.Lock()
        self._takes = 0

    def take(self, key: str) -> float:
        """Take a token for `key`: 0.0 when granted, else the seconds until one is available."""
        now = self._clock()
        with self._lock:
            bucket = self._buckets.get(key)
            if bucket is None:
                bucket = self._buckets[key] = _Bucket(tokens=float(self.burst), updated=now)
            else:
                elapsed = max(now - bucket.updated, 0.0)
                bucket.tokens = min(float(self.burst), bucket.tokens + elapsed * self.rate)
                bucket.updated = now
            self._takes += 1
            if self._takes % IDLE_BUCKETS_CHECK_EVERY == 0:
                self._drop_full(now)
            if bucket.tokens >= 1.0:
                bucket.tokens -= 1.0
                return 0.0
            return (1.0 - bucket.tokens) / self.rate

    def _drop_full(self, now: float) -> None:
        refill = self.burst / self.rate
        stale = [k for k, b in self._buckets.items() if now - b.updated >= refill]
        for k in stale:
            del self._buckets[k]


def retry_after_header(wait_seconds: float) -> str:
    """Retry-After in whole seconds (RFC 9110 allows no fractions), rounded up, at least 1."""
    return str(max(1, math.ceil(wait_seconds)))
