"""The lists by keyset: every item once, in (created_at, id) order, page after page, also when
items share a creation time; a deployment's webhooks and a webhook's deliveries kept to their
own; on SQLite and PostgreSQL (the API over them: tests/api/test_listing.py)."""

from __future__ import annotations

import uuid
from collections.abc import Callable, Sequence
from datetime import UTC, datetime, timedelta
from typing import Any

from sqlalchemy import Engine

from roadlink.db import listings
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.listings import Keyset
from roadlink.db.models import Deployment, Webhook, WebhookDelivery

T0 = datetime(2026, 1, 1, tzinfo=UTC)


def every_page(lister: Callable[..., Sequence[Any]], limit: int) -> list[list[uuid.UUID]]:
    pages, after = [], None
    while True:
        found = lister(after=after, limit=limit)
        page = list(found[:limit])
        pages.append([item.id for item in page])
        if len(found) <= limit:
            return pages
        after = Keyset(page[-1].created_at, page[-1].id)


def test_deployments_page_oldest_first_through_ties_in_time(engine: Engine) -> None:
    # Three share a creation time: the id breaks the tie, so none is shown twice or skipped.
    times = [T0, T0 + timedelta(seconds=1), T0 + timedelta(seconds=1), T0 + timedelta(seconds=1)]
    made = [
        Deployment(id=uuid.uuid4(), name=f"road {k}", created_at=t) for k, t in enumerate(times)
    ]
    sessions = make_session_factory(engine)
    with transaction(sessions) as session:
        session.add_all(made)
    expected = [d.id for d in sorted(made, key=lambda d: (d.created_at, d.id))]
    with sessions() as session:
        for limit in (1, 2, 3, 4, 5):
            pages = every_page(lambda **k: listings.list_deployments(session, **k), limit)
            assert [i for page in pages for i in page] == expected
            assert all(len(page) <= limit for page in pages)


def test_webhooks_oldest_first_and_deliveries_newest_first_of_their_own(engine: Engine) -> None:
    road, other = uuid.uuid4(), uuid.uuid4()
    hooks = [
        Webhook(
            id=uuid.uuid4(),
            deployment_id=d,
            url="https://a.b/",
            secret="whsec_x",
            event_types=["job.finished"],
            created_at=T0 + timedelta(seconds=k),
        )
        for k, d in enumerate((road, road, other))
    ]
    deliveries = [
        WebhookDelivery(
            id=uuid.uuid4(),
            webhook_id=hooks[w].id,
            event_id=uuid.uuid4(),
            event_type="job.finished",
            payload="{}",
            state="pending",
            attempts=0,
            created_at=T0 + timedelta(seconds=k // 2),  # in pairs of one time
        )
        for k, w in enumerate((0, 0, 0, 0, 1))
    ]
    sessions = make_session_factory(engine)
    with transaction(sessions) as session:
        session.add_all([Deployment(id=d, name="road", created_at=T0) for d in (road, other)])
        session.flush()
        session.add_all(hooks)
        session.flush()
        session.add_all(deliveries)
    with sessions() as session:
        pages = every_page(
            lambda **k: listings.list_webhooks(session, deployment_id=road, **k), limit=1
        )
        assert pages == [[hooks[0].id], [hooks[1].id]]
        pages = every_page(
            lambda **k: listings.list_deliveries(session, webhook_id=hooks[0].id, **k), limit=3
        )
        newest_first = sorted(deliveries[:4], key=lambda d: (d.created_at, d.id), reverse=True)
        assert pages == [[d.id for d in newest_first[:3]], [newest_first[3].id]]
