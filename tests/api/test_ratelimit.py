"""The per-key rate limit (`api/ratelimit.py`): token buckets, and the Retry-After they give.
(`tests/api/test_auth.py` checks the limit through the API.)"""

from __future__ import annotations

import pytest

from roadlink.api.ratelimit import IDLE_BUCKETS_CHECK_EVERY, TokenBuckets, retry_after_header


def test_token_buckets_refill_at_the_rate() -> None:
    now = [0.0]
    buckets = TokenBuckets(rate=2.0, burst=2, clock=lambda: now[0])
    assert [buckets.take("k") for _ in range(2)] == [0.0, 0.0]
    assert buckets.take("k") == pytest.approx(0.5)
    now[0] = 0.5
    assert buckets.take("k") == 0.0
    now[0] = 100.0  # idle buckets refill only up to the burst
    assert [buckets.take("k") == 0.0 for _ in range(3)] == [True, True, False]


def test_each_key_has_its_own_bucket_and_full_idle_ones_are_dropped() -> None:
    now = [0.0]
    buckets = TokenBuckets(rate=1.0, burst=1, clock=lambda: now[0])
    assert buckets.take("a") == 0.0 and buckets.take("b") == 0.0
    assert buckets.take("a") == pytest.approx(1.0)
    now[0] = 10.0
    for i in range(IDLE_BUCKETS_CHECK_EVERY):
        buckets.take(f"k{i}")
    assert "a" not in buckets._buckets and "b" not in buckets._buckets


@pytest.mark.parametrize(("rate", "burst"), [(0.0, 1), (-1.0, 1), (1.0, 0)])
def test_a_bucket_needs_a_positive_rate_and_burst(rate: float, burst: int) -> None:
    with pytest.raises(ValueError, match="rate > 0 and burst >= 1"):
        TokenBuckets(rate=rate, burst=burst)


def test_retry_after_is_whole_seconds_rounded_up_and_at_least_one() -> None:
    assert [retry_after_header(s) for s in (0.0, 0.01, 1.0, 1.2, 59.9)] == [
        "1",
        "1",
        "1",
        "2",
        "60",
    ]
