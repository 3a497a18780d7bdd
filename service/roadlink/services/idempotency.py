"""Idempotency-Keys, one rule for every endpoint that takes them (batches and jobs), after the
IETF draft "The Idempotency-Key HTTP Header Field":

- A key is a non-empty string of at most 200 characters (the API's header checks that).
- Its scope is its sender and the endpoint: a key belongs to the API key that sent it (or to
  the anonymous caller when authentication is disabled), on one endpoint (a deployment's
  batches, or jobs). Two API keys may use "1" without meeting.
- A retry with the same key and the same request gets what the first request created, says
  so (`Idempotent-Replayed`), and creates nothing. The same key with another request is a 422.
  Requests are told apart by `request_digest`: the content type and the body, JSON in a
  canonical form (so spacing and key order do not make two requests differ).
- Concurrent copies of one request: the first commit wins, and the others answer its replay.
  A copy waits at the key's unique constraint until the first commits, so no copy ever sees
  the first one in flight (the draft's 409 does not arise).
- Keys are forgotten after ROADLINK_IDEMPOTENCY_HOURS (`forget_expired_keys`).

Where each endpoint keeps its keys: `db/idempotency_records.py`.
"""

from __future__ import annotations

import contextlib
import hashlib
from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from typing import Generic, TypeVar

import orjson
from sqlalchemy.exc import IntegrityError
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db.engine import transaction
from roadlink.db.idempotency_records import Forgotten, forget_idempotency_keys
from roadlink.db.models import utcnow
from roadlink.services.problems import ProblemItem, ServiceProblem
from roadlink.settings import Settings

Created = TypeVar("Created")


@dataclass(frozen=True)
class IdempotentRequest:
    """A request sent with an Idempotency-Key: the key, its sender (with the endpoint, its
    scope), and the digest that tells a retry from another request."""

    key: str
    principal: str
    digest: str


def request_digest(content_type: str, body: bytes) -> str:
    """The sha256 of a request's content type and body; a JSON body counts as its canonical
    form (keys sorted, no spacing), so only what it says matters, not how it is spelled."""
    if content_type == "application/json":
        with contextlib.suppress(orjson.JSONDecodeError):  # not JSON after all: bytes as sent
            body = orjson.dumps(orjson.loads(body), option=orjson.OPT_SORT_KEYS)
    return hashlib.sha256(content_type.encode() + b"\0" + body).hexdigest()


@dataclass(frozen=True)
class Recorded(Generic[Created]):
    """What an earlier request with a key created: its digest, its name in a problem
    ("batch <id>"), and the answer it gets again."""

    digest: str
    name: str
    answer: Callable[[], Created]


def create_once(
    session: Session,
    request: IdempotentRequest | None,
    *,
    find: Callable[[IdempotentRequest], Recorded[Created] | None],
    create: Callable[[], Created],
    new_thing: str,
) -> tuple[Created, bool]:
    """Create and commit, unless an earlier request with this key did: then its answer again,
    created by nobody. Returns the answer and whether it is a replay.

    `find` looks the key up where its endpoint keeps them; `create` writes in `session` and
    records the key with what it created. Of several requests with one key sent at once,
    exactly one commits and the others meet the key's unique constraint (when writing or when
    committing): each of those rolls back and answers the winner's replay, as a retry after the
    fact would (or the 422 of a different body).
    """

    def earlier() -> Created | None:
        recorded = None if request is None else find(request)
        if recorded is None:
            return None
        _same_request(recorded, request, new_thing)
        return recorded.answer()

    replayed = earlier()
    if replayed is not None:
        return replayed, True
    try:
        created = create()
        session.commit()
        return created, False
    except IntegrityError:
        session.rollback()
        replayed = earlier()
        if replayed is None:  # some other constraint: the error handler answers it
            raise
        return replayed, True


def _same_request(recorded: Recorded[Created], request: IdempotentRequest | None, new: str) -> None:
    """422 when a key comes again with a request other than the one it was first used with."""
    if request is not None and recorded.digest != request.digest:
        raise ServiceProblem(
            422,
            f"Idempotency-Key '{request.key}' was used for a different request "
            f"({recorded.name}); use a new key for {new}",
            errors=[ProblemItem(field="Idempotency-Key", message="reused with a different body")],
        )


def forget_expired_keys(sessions: sessionmaker[Session], settings: Settings) -> Forgotten:
    """Forget the Idempotency-Keys older than the retention (ROADLINK_IDEMPOTENCY_HOURS)."""
    cutoff = utcnow() - timedelta(hours=settings.idempotency_hours)
    with transaction(sessions) as session:
        return forget_idempotency_keys(session, created_before=cutoff)
