"""Cursor pagination, one rule for every list: a page of at most `limit` items in a fixed total
order, (created_at, id), and an opaque cursor naming the last item shown.

The next page is the items after that one in the order (a keyset, not an offset), so an item
inserted while a client pages never moves the others: none of those that existed when it began
is shown twice or missed. The cursor is base64url of a small JSON document naming its list, so a
client treats it as opaque, and one made up or taken from another list is a 422 naming
`cursor`.
"""

from __future__ import annotations

import base64
import binascii
import json
import uuid
from collections.abc import Sequence
from datetime import datetime
from typing import Annotated, Any, Protocol
from urllib.parse import urlencode

from fastapi import Query, Request, Response

from roadlink.api.errors import parameter_problem
from roadlink.db.listings import Keyset

DEFAULT_LIMIT = 100
MAX_LIMIT = 1000
# Far longer than any cursor we make, short enough that decoding one costs nothing.
MAX_CURSOR_CHARS = 200

LimitQuery = Annotated[
    int,
    Query(
        ge=1,
        le=MAX_LIMIT,
        description=f"Most items on the page (at most {MAX_LIMIT}).",
    ),
]
CursorQuery = Annotated[
    str | None,
    Query(
        max_length=MAX_CURSOR_CHARS,
        description="Where the page starts: the `next_cursor` of the page before (opaque). "
        "Absent: the first page.",
    ),
]


class Keyed(Protocol):
    @property
    def created_at(self) -> datetime: ...

    @property
    def id(self) -> uuid.UUID: ...


def encode_cursor(kind: str, item: Keyed) -> str:
    document = json.dumps([kind, item.created_at.isoformat(), item.id.hex], separators=(",", ":"))
    return base64.urlsafe_b64encode(document.encode()).decode().rstrip("=")


def decode_cursor(kind: str, cursor: str | None) -> Keyset | None:
    """The position a cursor names, or None for the first page; a 422 for a cursor we did not
    make for this list."""
    if cursor is None:
        return None
    try:
        raw = base64.urlsafe_b64decode(cursor + "=" * (-len(cursor) % 4))
        named, created, item_id = json.loads(raw)
        if named != kind:
            raise ValueError(kind)
        at = datetime.fromisoformat(created)
        if at.tzinfo is None:
            raise ValueError(created)
        return Keyset(at, uuid.UUID(hex=item_id))
    except (ValueError, TypeError, binascii.Error, UnicodeDecodeError):
        raise parameter_problem(
            "cursor", f"not a cursor of this list ({kind}): pass the `next_cursor` of a page as is"
        ) from None


def page_of(
    kind: str,
    found: Sequence[Any],
    limit: int,
    request: Request,
    response: Response,
) -> tuple[list[Any], str | None, str | None]:
    """The page's items (the repository fetched one more than `limit`, to tell whether a next
    page exists), the next cursor and link; the link also goes in a `Link` header."""
    items = list(found[:limit])
    if len(found) <= limit:
        return items, None, None
    cursor = encode_cursor(kind, items[-1])
    return items, cursor, link_next(request, response, cursor)


def link_next(request: Request, response: Response, cursor: str, parameter: str = "cursor") -> str:
    """The next page's link, this request's path and query with `parameter` set to `cursor`,
    also sent as a `Link` header."""
    query = [(k, v) for k, v in request.query_params.multi_items() if k != parameter]
    link = f"{request.url.path}?{urlencode([*query, (parameter, cursor)])}"
    response.headers["Link"] = f'<{link}>; rel="next"'
    return link


LINK_HEADER = {
    "Link": {
        "description": 'The next page, as `<link>; rel="next"` (RFC 8288); absent on the last.',
        "schema": {"type": "string"},
    }
}


def date_time_or_null(schema: dict[str, Any]) -> None:
    """A list's time filter (jobs' `created_since`) is read as text and parsed by `aware_time`;
    its schema says it is the date-time it must be."""
    schema["anyOf"][0]["format"] = "date-time"


def aware_time(field: str, text: str) -> datetime:
    """An ISO 8601 time with its zone (not a bare number, which pydantic would read as a Unix
    time, nor a time without a zone: the service keeps UTC)."""
    try:
        at = datetime.fromisoformat(text)
    except ValueError:
        at = None
    if at is None or at.tzinfo is None:
        raise parameter_problem(
            field, f"give an ISO 8601 time with its zone, e.g. 2026-01-01T00:00:00Z, not {text!r}"
        )
    return at
