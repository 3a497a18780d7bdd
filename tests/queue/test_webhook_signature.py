"""Webhook signatures: HMAC-SHA256 of `<t>.<body>` with the webhook's secret, and the secrets
themselves (the receiver's side, the snippet in docs/service.md: test_webhook_dispatch.py)."""

from __future__ import annotations

from roadlink.queue.webhook_signature import SECRET_PREFIX, new_secret, signature


def test_the_signature_is_hmac_sha256_of_time_dot_body() -> None:
    # Computed independently: printf '%s' '1767225600.{"id":"e1"}' | openssl dgst -sha256
    # -hmac whsec_test
    assert signature("whsec_test", 1767225600, b'{"id":"e1"}') == (
        "t=1767225600,v1=454f7f9597bf74f9ee7b13eab0ac98e91665e9039d783864ee4129a0f2c9c88f"
    )


def test_the_time_the_body_and_the_secret_each_change_the_signature() -> None:
    base = signature("whsec_a", 100, b"{}")
    assert len({base, signature("whsec_b", 100, b"{}"), signature("whsec_a", 101, b"{}")}) == 3
    assert base != signature("whsec_a", 100, b"{ }")


def test_secrets_are_prefixed_and_new_each_time() -> None:
    secrets = {new_secret() for _ in range(50)}
    assert len(secrets) == 50
    # 32 random bytes, base64url without padding: 43 characters after the prefix.
    assert all(s.startswith(SECRET_PREFIX) and len(s) == len(SECRET_PREFIX) + 43 for s in secrets)
