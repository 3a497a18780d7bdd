"""Lists a page at a time: cursors, `next` links, filters, and pages that stay right while
items are inserted; a deployment's batches; `Location` on what a 201 or 202 created."""

from __future__ import annotations

import threading
from datetime import UTC, datetime, timedelta
from typing import Any

import pytest
from fastapi.testclient import TestClient

from tests.helpers import assert_problem, post_csv_batch

CSV = "position,velocity,timestamp,sensor_id\n0,30,1,A\n100,30,4.3,B\n0,20,2,A\n100,20,7,B\n"


def post_batch(
    client: TestClient, deployment: str, *, associator: str | None = None
) -> dict[str, Any]:
    return post_csv_batch(
        client, deployment, CSV, **({"associator": associator} if associator else {})
    )


def every_page(client: TestClient, path: str, **params: Any) -> list[list[str]]:
    """The ids of each page, following `next` to the end."""
    pages = []
    page = client.get(path, params=params)
    while True:
        assert page.status_code == 200, page.text
        body = page.json()
        pages.append([item["id"] for item in body["items"]])
        if body["next"] is None:
            assert body["next_cursor"] is None and "link" not in page.headers
            return pages
        assert page.headers["link"] == f'<{body["next"]}>; rel="next"'
        assert f"cursor={body['next_cursor']}" in body["next"]
        page = client.get(body["next"])


def test_deployments_come_oldest_first_in_pages_of_limit(client):
    made = [
        client.post("/v1/deployments", json={"name": f"road {k}"}).json()["id"] for k in range(5)
    ]
    assert every_page(client, "/v1/deployments", limit=2) == [made[:2], made[2:4], made[4:]]
    assert every_page(client, "/v1/deployments") == [made]


def test_a_deployments_batches_newest_first_with_sensors_and_job(client, deployment):
    first = post_batch(client, deployment["id"], associator="kmeans")
    second = post_batch(client, deployment["id"])
    other = client.post("/v1/deployments", json={"name": "elsewhere"}).json()["id"]
    post_batch(client, other)
    path = f"/v1/deployments/{deployment['id']}/batches"
    assert every_page(client, path, limit=1) == [[second["id"]], [first["id"]]]
    items = client.get(path).json()["items"]
    assert [b["sensors"] for b in items] == [["A", "B"], ["A", "B"]]
    assert items[1]["job"]["id"] == first["job"]["id"] and items[0]["job"] is None
    assert {k: v for k, v in items[1].items() if k != "sensors"} == first
    missing = "/v1/deployments/00000000-0000-0000-0000-000000000000/batches"
    assert_problem(client.get(missing), 404)


def test_jobs_filter_by_state_deployment_and_created_since(client, deployment):
    before = datetime.now(UTC) - timedelta(seconds=1)
    jobs = [post_batch(client, deployment["id"], associator="kmeans")["job"] for _ in range(3)]
    other = client.post("/v1/deployments", json={"name": "elsewhere"}).json()["id"]
    post_batch(client, other, associator="kmeans")
    client.post(f"/v1/jobs/{jobs[0]['id']}/cancel")
    newest_first = [j["id"] for j in reversed(jobs)]
    mine = {"deployment_id": deployment["id"]}
    assert every_page(client, "/v1/jobs", limit=2, **mine) == [newest_first[:2], newest_first[2:]]
    assert every_page(client, "/v1/jobs", state="cancelled", **mine) == [[jobs[0]["id"]]]
    assert every_page(client, "/v1/jobs", state="queued", **mine) == [newest_first[:2]]
    since = {"created_since": before.isoformat()}
    assert len(every_page(client, "/v1/jobs", **since)[0]) == 4
    later = {"created_since": (datetime.now(UTC) + timedelta(hours=1)).isoformat()}
    assert every_page(client, "/v1/jobs", **later) == [[]]


@pytest.mark.parametrize(
    ("path", "params", "field"),
    [
        ("/v1/jobs", {"cursor": "not-a-cursor"}, "cursor"),
        (
            "/v1/deployments",
            {"cursor": "WyJqb2JzIiwiMjAyNi0wMS0wMVQwMDowMDowMCswMDowMCIsIjAwIl0"},
            "cursor",
        ),
        ("/v1/jobs", {"created_since": "2026-01-01T00:00:00"}, "created_since"),
        ("/v1/jobs", {"created_since": "1700000000"}, "created_since"),
        ("/v1/jobs", {"limit": "1001"}, "limit"),
        ("/v1/jobs", {"limit": "0"}, "limit"),
    ],
)
def test_a_bad_cursor_time_or_limit_is_a_422_naming_it(client, path, params, field):
    problem = assert_problem(client.get(path, params=params), 422)
    assert [e["field"] for e in problem["errors"]] == [field]


def test_a_cursor_of_another_list_is_refused(client):
    for k in range(2):
        client.post("/v1/deployments", json={"name": f"road {k}"})
    cursor = client.get("/v1/deployments", params={"limit": 1}).json()["next_cursor"]
    assert client.get("/v1/deployments", params={"cursor": cursor}).status_code == 200
    problem = assert_problem(client.get("/v1/jobs", params={"cursor": cursor}), 422)
    assert problem["errors"][0]["field"] == "cursor"


def test_paging_while_others_insert_shows_each_item_that_existed_exactly_once(client, deployment):
    """Jobs are inserted between every two pages and from another thread meanwhile; those that
    existed when paging began come each exactly once, in order (an offset would have repeated
    them as new ones pushed them down)."""
    existing = [
        post_batch(client, deployment["id"], associator="kmeans")["job"]["id"] for _ in range(12)
    ]
    stop = threading.Event()
    inserted: list[str] = []

    def insert() -> None:
        while not stop.is_set():
            inserted.append(post_batch(client, deployment["id"], associator="kmeans")["job"]["id"])

    inserter = threading.Thread(target=insert)
    inserter.start()
    seen: list[str] = []
    try:
        page = client.get("/v1/jobs", params={"limit": 3, "deployment_id": deployment["id"]}).json()
        while True:
            seen += [job["id"] for job in page["items"]]
            # One more at once, whatever the thread is doing: a page never depends on luck.
            inserted.append(post_batch(client, deployment["id"], associator="kmeans")["job"]["id"])
            if page["next"] is None:
                break
            page = client.get(page["next"]).json()
    finally:
        stop.set()
        inserter.join()
    assert len(inserted) >= 5
    assert len(seen) == len(set(seen)), "an item was shown twice"
    assert [i for i in seen if i in existing] == list(reversed(existing))


def test_created_resources_carry_their_location(client, deployment):
    created = client.post("/v1/deployments", json={"name": "road"})
    assert created.headers["location"] == f"/v1/deployments/{created.json()['id']}"
    batch = client.post(
        f"/v1/deployments/{deployment['id']}/batches",
        content=CSV,
        headers={"content-type": "text/csv"},
    )
    assert batch.headers["location"] == f"/v1/batches/{batch.json()['id']}"
    assert client.get(batch.headers["location"]).json() == batch.json()
    job = client.post("/v1/jobs", json={"batch_id": batch.json()["id"], "associator": "kmeans"})
    assert job.status_code == 202
    assert job.headers["location"] == f"/v1/jobs/{job.json()['id']}"
    link = client.post(f"/v1/jobs/{job.json()['id']}/page-link")
    assert link.status_code == 201 and link.headers["location"] == link.json()["url"]
    simulated = client.post(
        "/v1/simulations", json={"deployment_id": deployment["id"], "preset": "small", "seed": 1}
    )
    assert simulated.headers["location"] == f"/v1/batches/{simulated.json()['id']}"


def test_a_deployments_webhooks_and_their_deliveries_come_in_pages(client, worker, deployment):
    hooks = f"/v1/deployments/{deployment['id']}/webhooks"
    made = [client.post(hooks, json={"url": f"http://127.0.0.1:9/{k}"}).json()["id"] for k in "abc"]
    assert every_page(client, hooks, limit=2) == [made[:2], made[2:]]
    for _ in range(3):
        post_batch(client, deployment["id"], associator="kmeans")
        assert worker.run_once()
    deliveries = f"{hooks}/{made[0]}/deliveries"
    newest_first = [d["id"] for d in client.get(deliveries).json()["items"]]
    assert len(set(newest_first)) == 3
    assert every_page(client, deliveries, limit=2) == [newest_first[:2], newest_first[2:]]
    cursor = client.get(hooks, params={"limit": 1}).json()["next_cursor"]
    problem = assert_problem(client.get(deliveries, params={"cursor": cursor}), 422)
    assert problem["errors"][0]["field"] == "cursor"
