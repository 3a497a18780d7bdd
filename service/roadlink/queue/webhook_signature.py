"""Webhook signatures, in the style of Stripe's: `Roadlink-Signature: t=<unix time>,v1=<hex>`,
where v1 is HMAC-SHA256, keyed with the webhook's secret, of `<t>.<body>`. Signing the time
with the body lets a receiver refuse a replayed old delivery (docs/service.md, Webhooks)."""

from __future__ import annotations

import hashlib
import hmac
import secrets

SIGNATURE_HEADER = "Roadlink-Signature"

SECRET_PREFIX = "whsec_"


def new_secret() -> str:
    """A webhook's signing secret: 32 random bytes, URL-safe."""
    return SECRET_PREFIX + secrets.token_urlsafe(32)


def signature(secret: str, timestamp: int, body: bytes) -> str:
    """The header value that signs `body` sent at `timestamp` (whole seconds since the epoch)."""
    signed = str(timestamp).encode() + b"." + body
    digest = hmac.new(secret.encode(), signed, hashlib.sha256).hexdigest()
    return f"t={timestamp},v1={digest}"
