"""Signed, expiring links to a job's page, so that a browser can open it without an API key.

A browser sends no `Authorization` header, and an API key must not end up in a URL, a bookmark
or a cookie jar. So a caller allowed to read a job asks for a link (`POST
/v1/jobs/{id}/page-link`) and gets `/jobs/{id}?token=<prefix>.<expires>.<signature>`:

- `prefix` names the API key that made the link; `expires` is a Unix time;
- `signature` is HMAC-SHA256 over the job id and `expires`, keyed with the key's stored sha256.
  That hash never leaves the database, so only the service can sign; no new secret has to be
  configured or shared between API replicas; and revoking the key revokes its links.

A token opens one job's page, read-only, until it expires, and only while the key that made it
is live and still allowed to read that job. Whoever can read the database could sign links, but
they can read the jobs there anyway.
"""

from __future__ import annotations

import base64
import hashlib
import hmac
import uuid
from datetime import UTC, datetime

from sqlalchemy import select
from sqlalchemy.orm import Session

from roadlink.association.numbers import parse_unsigned
from roadlink.db.models import ApiKey

DEFAULT_LIFETIME_SECONDS = 3600
MAX_LIFETIME_SECONDS = 7 * 24 * 3600
_PURPOSE = b"roadlink job page link v1"


def page_token(key: ApiKey, job_id: uuid.UUID, expires: int) -> str:
    """The token that opens `job_id`'s page until `expires` (Unix seconds), made by `key`."""
    return f"{key.prefix}.{expires}.{_signature(key, job_id, expires)}"


def token_key(
    session: Session, *, token: str, job_id: uuid.UUID, now: datetime | None = None
) -> ApiKey | None:
    """The live key that signed `token` for `job_id`, or None when the token is malformed,
    forged, for another job, expired, or its key is unknown or revoked."""
    prefix, _, rest = token.partition(".")
    expires_text, _, signature = rest.partition(".")
    expires = parse_unsigned(expires_text, max_digits=12)
    if not (prefix and signature) or expires is None:
        return None
    if expires <= (now or datetime.now(UTC)).timestamp():
        return None
    key = session.scalars(select(ApiKey).where(ApiKey.prefix == prefix)).first()
    if key is None or key.revoked_at is not None:
        return None
    if not hmac.compare_digest(signature, _signature(key, job_id, expires)):
        return None
    return key


def _signature(key: ApiKey, job_id: uuid.UUID, expires: int) -> str:
    message = b"\n".join((_PURPOSE, str(job_id).encode(), str(expires).encode()))
    digest = hmac.new(bytes.fromhex(key.secret_sha256), message, hashlib.sha256).digest()
    return base64.urlsafe_b64encode(digest).rstrip(b"=").decode()
