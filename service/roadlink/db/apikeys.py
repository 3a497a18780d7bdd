"""API keys: their format, and the data functions that store, find, list and revoke them.

A key reads `rl_<prefix>_<secret>`: the prefix (8 hex characters) is public and names the key in
listings and logs; the secret is 32 random bytes (`secrets.token_urlsafe`, 256 bits). The
database holds only the sha256 of the whole key. A slow password hash (bcrypt, scrypt, argon2)
exists to make guessing a *low-entropy* password from its stolen hash expensive; a 256-bit random
secret cannot be guessed whatever the hash costs, so sha256 loses nothing and keeps every request
cheap. Keys are compared with `hmac.compare_digest`, in constant time.
"""

from __future__ import annotations

import hashlib
import hmac
import secrets
import uuid
from collections.abc import Sequence
from dataclasses import dataclass

from sqlalchemy import select, update
from sqlalchemy.orm import Session

from roadlink.db.models import ApiKey, ApiKeyScope, utcnow

KEY_MARK = "rl"
PREFIX_BYTES = 4
SECRET_BYTES = 32


@dataclass(frozen=True)
class IssuedKey:
    """A newly created key: the stored row, and the key itself (shown once, never stored)."""

    row: ApiKey
    key: str


def key_sha256(key: str) -> str:
    """The stored form of a key."""
    return hashlib.sha256(key.encode()).hexdigest()


def key_prefix(key: str) -> str | None:
    """The public prefix of a well-formed key, or None when `key` is not one of ours."""
    mark, _, rest = key.partition("_")
    prefix, _, secret = rest.partition("_")
    if mark != KEY_MARK or len(prefix) != 2 * PREFIX_BYTES or not secret:
        return None
    return prefix


def create_api_key(
    session: Session,
    *,
    scope: ApiKeyScope,
    deployment_ids: Sequence[uuid.UUID] = (),
    name: str | None = None,
) -> IssuedKey:
    """A new random key with `scope` (ingest keys name their deployments). Flushes, does not
    commit; the key is returned once and only its hash is kept."""
    if scope is ApiKeyScope.INGEST and not deployment_ids:
        raise ValueError("an ingest key must name at least one deployment it may post to")
    if scope is not ApiKeyScope.INGEST and deployment_ids:
        raise ValueError(
            f"only ingest keys are limited to deployments; a {scope.value} key covers them all"
        )
    prefix = secrets.token_hex(PREFIX_BYTES)
    key = f"{KEY_MARK}_{prefix}_{secrets.token_urlsafe(SECRET_BYTES)}"
    row = ApiKey(
        prefix=prefix,
        secret_sha256=key_sha256(key),
        name=name,
        scope=scope.value,
        deployment_ids=[str(d) for d in dict.fromkeys(deployment_ids)] or None,
    )
    session.add(row)
    session.flush()
    return IssuedKey(row=row, key=key)


def authenticate_api_key(session: Session, *, key: str) -> ApiKey | None:
    """The live (not revoked) key row that `key` is, or None.

    The row is found by the public prefix; the secret is then checked by comparing hashes in
    constant time, so response timing reveals nothing about how much of a guess was right.
    """
    prefix = key_prefix(key)
    if prefix is None:
        return None
    row = session.scalars(select(ApiKey).where(ApiKey.prefix == prefix)).first()
    if row is None or row.revoked_at is not None:
        return None
    if not hmac.compare_digest(row.secret_sha256, key_sha256(key)):
        return None
    return row


def list_api_keys(session: Session, *, include_revoked: bool = True) -> Sequence[ApiKey]:
    """Keys, oldest first (their hashes are in the rows; callers show prefixes only)."""
    query = select(ApiKey).order_by(ApiKey.created_at, ApiKey.id)
    if not include_revoked:
        query = query.where(ApiKey.revoked_at.is_(None))
    return session.scalars(query).all()


def find_api_key(session: Session, *, reference: str) -> ApiKey | None:
    """A key by its id or its public prefix."""
    try:
        key_id = uuid.UUID(reference)
    except ValueError:
        return session.scalars(select(ApiKey).where(ApiKey.prefix == reference)).first()
    return session.get(ApiKey, key_id)


def revoke_api_key(session: Session, *, key_id: uuid.UUID) -> bool:
    """Revoke a key (from now on it is refused with 401); False when it was revoked already."""
    revoked = session.execute(
        update(ApiKey)
        .where(ApiKey.id == key_id, ApiKey.revoked_at.is_(None))
        .values(revoked_at=utcnow())
    )
    return bool(revoked.rowcount)  # type: ignore[attr-defined]


def has_admin_key(session: Session) -> bool:
    """True when some live admin key exists (else a fresh service needs its first key)."""
    query = select(ApiKey.id).where(
        ApiKey.scope == ApiKeyScope.ADMIN.value, ApiKey.revoked_at.is_(None)
    )
    return session.scalars(query.limit(1)).first() is not None
