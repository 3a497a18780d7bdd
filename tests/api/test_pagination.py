"""Cursors and pages as units: a cursor names its list and the last item shown, a page is cut
at `limit` with the next link built from the request (whole lists through the API:
tests/api/test_listing.py)."""

from __future__ import annotations

import base64
import uuid
from datetime import UTC, datetime
from typing import NamedTuple

import pytest
from fastapi import Response
from starlette.requests import Request

from roadlink.api.errors import ApiProblem
from roadlink.api.pagination import aware_time, decode_cursor, encode_cursor, page_of
from roadlink.db.listings import Keyset


class Item(NamedTuple):
    created_at: datetime
    id: uuid.UUID


def item(second: int) -> Item:
    return Item(datetime(2026, 1, 1, 0, 0, second, 123456, tzinfo=UTC), uuid.uuid4())


def request(path: str, query: str) -> Request:
    scope = {"type": "http", "method": "GET", "path": path, "query_string": query.encode()}
    return Request({**scope, "headers": []})


def test_a_cursor_names_the_last_item_exactly_and_is_url_safe() -> None:
    last = item(5)
    cursor = encode_cursor("jobs", last)
    assert decode_cursor("jobs", cursor) == Keyset(last.created_at, last.id)
    assert set(cursor) <= set("ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789-_")
    assert decode_cursor("jobs", None) is None


def _encoded(text: str) -> str:
    return base64.urlsafe_b64encode(text.encode()).decode().rstrip("=")


@pytest.mark.parametrize(
    "cursor",
    [
        "not a cursor",
        "",
        _encoded('["jobs","2026-01-01T00:00:00","' + "0" * 32 + '"]'),  # no zone
        _encoded('["jobs","2026-01-01T00:00:00+00:00","xyz"]'),
        _encoded('["jobs","2026-01-01T00:00:00+00:00"]'),
        _encoded("[1,2,3]"),
    ],
)
def test_a_cursor_we_did_not_make_is_a_422_naming_cursor(cursor: str) -> None:
    with pytest.raises(ApiProblem) as refused:
        decode_cursor("jobs", cursor)
    assert refused.value.status == 422
    assert [e.field for e in refused.value.errors] == ["cursor"]


def test_a_cursor_of_another_list_is_refused() -> None:
    with pytest.raises(ApiProblem):
        decode_cursor("webhooks", encode_cursor("deliveries", item(1)))


def test_a_page_with_more_items_than_its_limit_links_the_next_keeping_the_query() -> None:
    found = [item(s) for s in range(4)]  # the repository's limit + 1
    response = Response()
    asked = request("/v1/jobs", "state=queued&limit=3&cursor=old")
    items, cursor, link = page_of("jobs", found, 3, asked, response)
    assert items == found[:3] and cursor == encode_cursor("jobs", found[2])
    assert link == f"/v1/jobs?state=queued&limit=3&cursor={cursor}"
    assert response.headers["link"] == f'<{link}>; rel="next"'


def test_the_last_page_has_no_cursor_link_or_header() -> None:
    found = [item(s) for s in range(3)]
    response = Response()
    assert page_of("jobs", found, 3, request("/v1/jobs", "limit=3"), response) == (
        found,
        None,
        None,
    )
    assert "link" not in response.headers


def test_a_time_filter_needs_its_zone() -> None:
    assert aware_time("created_since", "2026-01-01T00:00:00Z") == datetime(2026, 1, 1, tzinfo=UTC)
    for text in ("2026-01-01T00:00:00", "1767225600", "yesterday"):
        with pytest.raises(ApiProblem) as refused:
            aware_time("created_since", text)
        assert refused.value.errors[0].field == "created_since"
