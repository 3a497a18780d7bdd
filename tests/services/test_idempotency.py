"""Idempotency-Keys, one rule for batches and jobs: a key is a non-empty string of at most 200
characters, scoped by its sender and endpoint; a retry of the same request (however its JSON is
spelled) returns what the first created and creates nothing; the same key with another request
is 422; keys are forgotten after the retention, not before."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from datetime import timedelta
from typing import Any

import orjson
import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, select, update

from roadlink.association.detections import Detections
from roadlink.db.engine import make_session_factory
from roadlink.db.models import Batch, JobIdempotencyKey, utcnow
from roadlink.services.idempotency import forget_expired_keys, request_digest
from roadlink.settings import Settings
from tests.helpers import MakeKey, assert_problem, bearer, detection_rows, row_counts


def _batch(client: TestClient, deployment: dict[str, Any], csv: str, key: str | None) -> Any:
    headers = {"content-type": "text/csv", **({"Idempotency-Key": key} if key else {})}
    return client.post(f"/v1/deployments/{deployment['id']}/batches", content=csv, headers=headers)


def test_keys_are_kept_for_the_retention_then_forgotten(
    client: TestClient,
    engine: Engine,
    settings: Settings,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    batch = _batch(client, deployment, paper_csv, "batch-key").json()
    job = client.post("/v1/jobs", json={"batch_id": batch["id"]}, headers={"Idempotency-Key": "j"})
    sessions = make_session_factory(engine)
    # Nothing is forgotten within the retention (24 hours by default)...
    forgotten = forget_expired_keys(sessions, settings)
    assert (forgotten.batches, forgotten.jobs) == (0, 0)
    replay = _batch(client, deployment, paper_csv, "batch-key")
    assert replay.headers["idempotent-replayed"] == "true"
    # ...and everything older is; the batch and the job themselves stay.
    aged = utcnow() - timedelta(hours=settings.idempotency_hours, minutes=1)
    with sessions.begin() as session:
        session.execute(update(Batch).values(created_at=aged))
        session.execute(update(JobIdempotencyKey).values(created_at=aged))
    forgotten = forget_expired_keys(sessions, settings)
    assert (forgotten.batches, forgotten.jobs) == (1, 1)
    with sessions() as session:
        assert session.scalars(select(Batch.idempotency_key)).all() == [None]
    assert client.get(f"/v1/jobs/{job.json()['id']}").status_code == 200
    again = _batch(client, deployment, paper_csv, "batch-key")
    assert again.status_code == 201 and again.json()["id"] != batch["id"]


@dataclass(frozen=True)
class Endpoint:
    """An endpoint that takes an Idempotency-Key: where to post, a request (as a dict), another
    request, and what the created thing is called in a problem."""

    name: str
    url: str
    request: dict[str, Any]
    other: dict[str, Any]
    created: str  # "batch" | "job"


def _batches(client: TestClient, deployment: dict[str, Any], paper_batch: Detections) -> Endpoint:
    rows = detection_rows(paper_batch)
    return Endpoint(
        "batches",
        f"/v1/deployments/{deployment['id']}/batches",
        {"detections": rows},
        {"detections": rows[:50]},
        "batch",
    )


def _jobs(client: TestClient, deployment: dict[str, Any], paper_batch: Detections) -> Endpoint:
    url = f"/v1/deployments/{deployment['id']}/batches"
    batch = client.post(url, json={"detections": detection_rows(paper_batch)}).json()
    request = {"batch_id": batch["id"], "associator": "kmeans"}
    return Endpoint("jobs", "/v1/jobs", request, {**request, "associator": "kmeans++"}, "job")


EndpointOf = Callable[[TestClient, dict[str, Any], Detections], Endpoint]


@pytest.fixture
def endpoint(
    request: pytest.FixtureRequest,
    client: TestClient,
    deployment: dict[str, Any],
    paper_batch: Detections,
) -> Endpoint:
    endpoint_of: EndpointOf = request.param
    return endpoint_of(client, deployment, paper_batch)


BOTH = pytest.mark.parametrize(
    "endpoint", [_batches, _jobs], ids=["batches", "jobs"], indirect=True
)


def _post(
    client: TestClient, endpoint: Endpoint, body: dict[str, Any] | bytes, key: str, **headers: str
) -> Any:
    content = body if isinstance(body, bytes) else orjson.dumps(body)
    sent = {"content-type": "application/json", "Idempotency-Key": key, **headers}
    return client.post(endpoint.url, content=content, headers=sent)


@BOTH
@pytest.mark.parametrize("key", ["", "k" * 201], ids=["empty", "201 characters"])
def test_a_key_is_a_non_empty_string_of_at_most_200_characters(
    client: TestClient, engine: Engine, endpoint: Endpoint, key: str
) -> None:
    before = row_counts(engine)
    problem = assert_problem(_post(client, endpoint, endpoint.request, key), 422)
    assert problem["errors"][0]["field"] == "Idempotency-Key"
    assert row_counts(engine) == before
    assert _post(client, endpoint, endpoint.request, "k" * 200).status_code in (201, 202)


@BOTH
def test_a_retry_however_spelled_returns_what_the_first_created_and_creates_nothing(
    client: TestClient, engine: Engine, endpoint: Endpoint
) -> None:
    first = _post(client, endpoint, endpoint.request, "retry-1")
    assert first.status_code in (201, 202) and "idempotent-replayed" not in first.headers
    before = row_counts(engine)
    # The same request, its keys in another order and spaced out.
    respelled = orjson.dumps(dict(reversed(endpoint.request.items())), option=orjson.OPT_INDENT_2)
    again = _post(
        client,
        endpoint,
        respelled,
        "retry-1",
        **{"content-type": "application/json; charset=utf-8"},
    )
    assert again.status_code == first.status_code
    assert again.headers["idempotent-replayed"] == "true"
    assert again.json()["id"] == first.json()["id"]
    assert row_counts(engine) == before


@BOTH
def test_the_same_key_with_another_request_is_refused(
    client: TestClient, engine: Engine, endpoint: Endpoint
) -> None:
    first = _post(client, endpoint, endpoint.request, "reused")
    before = row_counts(engine)
    problem = assert_problem(_post(client, endpoint, endpoint.other, "reused"), 422)
    assert f"{endpoint.created} {first.json()['id']}" in problem["detail"]
    assert "'reused'" in problem["detail"]
    assert problem["errors"][0]["field"] == "Idempotency-Key"
    assert row_counts(engine) == before
    fresh = _post(client, endpoint, endpoint.other, "fresh")
    assert fresh.status_code in (201, 202) and fresh.json()["id"] != first.json()["id"]


@BOTH
def test_a_key_belongs_to_the_api_key_that_sent_it(
    client: TestClient, endpoint: Endpoint, make_key: MakeKey
) -> None:
    mine = _post(client, endpoint, endpoint.request, "1")
    theirs = _post(client, endpoint, endpoint.request, "1", **bearer(make_key("admin")))
    assert mine.status_code == theirs.status_code
    assert "idempotent-replayed" not in theirs.headers
    assert mine.json()["id"] != theirs.json()["id"]


@BOTH
def test_a_key_belongs_to_its_endpoint(
    client: TestClient, endpoint: Endpoint, deployment: dict[str, Any], paper_batch: Detections
) -> None:
    here = _post(client, endpoint, endpoint.request, "shared")
    # The other endpoint: jobs for batches, and a deployment's batches for jobs.
    elsewhere = (_jobs if endpoint.name == "batches" else _batches)(client, deployment, paper_batch)
    there = _post(client, elsewhere, elsewhere.request, "shared")
    assert here.status_code in (201, 202) and there.status_code in (201, 202)
    assert "idempotent-replayed" not in there.headers


def test_a_batch_key_belongs_to_its_deployment(
    client: TestClient, deployment: dict[str, Any], paper_batch: Detections
) -> None:
    other = client.post("/v1/deployments", json={"name": "other road"}).json()
    body = {"detections": detection_rows(paper_batch)}
    first = client.post(
        f"/v1/deployments/{deployment['id']}/batches", json=body, headers={"Idempotency-Key": "d"}
    )
    second = client.post(
        f"/v1/deployments/{other['id']}/batches", json=body, headers={"Idempotency-Key": "d"}
    )
    assert first.status_code == second.status_code == 201
    assert "idempotent-replayed" not in second.headers


def test_a_json_digest_is_of_what_it_says_not_how_it_is_spelled() -> None:
    assert request_digest("application/json", b'{"a": 1, "b": [1.5]}') == request_digest(
        "application/json", b'{\n  "b": [1.5],\n  "a": 1\n}'
    )
    assert request_digest("application/json", b'{"a": 1}') != request_digest(
        "application/json", b'{"a": 2}'
    )


def test_other_bodies_are_digested_as_sent_with_their_content_type() -> None:
    csv = b"position,velocity,timestamp,sensor_id\n0,30,1,S1\n"
    assert request_digest("text/csv", csv) != request_digest("text/csv", csv.replace(b",", b", "))
    assert request_digest("text/csv", b"{}") != request_digest("application/json", b"{}")
    # A body that says it is JSON but is not: its bytes, so that the parse error answers it.
    assert request_digest("application/json", b"{oops") == request_digest(
        "application/json", b"{oops"
    )
    assert request_digest("application/json", b"{oops") != request_digest(
        "application/json", b"{oops "
    )
