"""API keys: 401 without a valid key, 403 outside the key's scope or deployments, keys stored
as hashes only, the per-key rate limit, and the switch that turns authentication off."""

from __future__ import annotations

import re
import uuid
from typing import Any

import pytest
from fastapi import APIRouter
from fastapi.testclient import TestClient
from sqlalchemy import Engine, text
from typer.testing import CliRunner

from roadlink.api import create_app
from roadlink.api.auth import POLICY, check_policy_covers
from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.cli import app as cli
from roadlink.db.apikeys import key_sha256
from roadlink.settings import Settings
from tests.helpers import MakeKey, assert_problem, bearer


def v1_routes(client: TestClient) -> list[tuple[str, str]]:
    """Every (method, path) under /v1 the app documents, path parameters filled with an id."""
    paths = client.get("/openapi.json").json()["paths"]
    return [
        (method.upper(), re.sub(r"\{[a-z_]+\}", str(uuid.uuid4()), path))
        for path, operations in paths.items()
        if path.startswith("/v1")
        for method in operations
    ]


def test_every_documented_v1_operation_declares_the_bearer_scheme(client: TestClient) -> None:
    spec = client.get("/openapi.json").json()
    assert spec["components"]["securitySchemes"]["ApiKey"] == {
        "type": "http",
        "scheme": "bearer",
        "description": spec["components"]["securitySchemes"]["ApiKey"]["description"],
    }
    for path, operations in spec["paths"].items():
        for method, operation in operations.items():
            if path.startswith("/v1"):
                assert operation["security"] == [{"ApiKey": []}], (method, path)
                assert {"401", "403", "429"} <= operation["responses"].keys(), (method, path)
                assert (method.upper(), path) in POLICY
            else:
                assert "security" not in operation, (method, path)


def test_a_route_without_an_access_rule_is_refused_at_startup() -> None:
    router = APIRouter(prefix="/v1/unguarded")

    @router.get("")
    def unguarded() -> None: ...

    with pytest.raises(RuntimeError, match="GET /v1/unguarded"):
        check_policy_covers([router])


@pytest.fixture
def anonymous(client: TestClient) -> TestClient:
    """The same app, with no key."""
    return TestClient(client.app)


@pytest.fixture
def world(client: TestClient, paper_csv: str) -> dict[str, Any]:
    """Two deployments; in the first a batch with its job (made with the admin key)."""
    first = client.post("/v1/deployments", json={"name": "first"}).json()
    second = client.post("/v1/deployments", json={"name": "second"}).json()
    batch = client.post(
        f"/v1/deployments/{first['id']}/batches?associator=kmeans",
        content=paper_csv,
        headers={"content-type": "text/csv"},
    ).json()
    return {"first": first["id"], "second": second["id"], "batch": batch}


def test_every_v1_route_needs_a_key_and_the_health_routes_do_not(
    anonymous: TestClient,
) -> None:
    routes = v1_routes(anonymous)
    assert len(routes) == len(POLICY) >= 12
    for method, path in routes:
        response = anonymous.request(method, path)
        problem = assert_problem(response, 401)
        assert response.headers["www-authenticate"].startswith("Bearer"), path
        assert "Authorization: Bearer" in problem["detail"]
    for path in ("/healthz", "/readyz", "/metrics"):
        assert anonymous.get(path).status_code == 200, path


@pytest.mark.parametrize(
    "authorization",
    [
        "Bearer rl_00000000_not-a-key-we-issued",
        "Bearer garbage",
        "Basic dXNlcjpwYXNz",
        "Bearer ",
    ],
)
def test_unknown_or_malformed_keys_are_401(anonymous: TestClient, authorization: str) -> None:
    response = anonymous.get("/v1/deployments", headers={"Authorization": authorization})
    assert_problem(response, 401)
    assert "Bearer" in response.headers["www-authenticate"]


def test_a_key_with_a_right_prefix_and_a_wrong_secret_is_401(
    anonymous: TestClient, make_key: MakeKey
) -> None:
    key = make_key("read")
    forged = key[:-4] + ("AAAA" if not key.endswith("AAAA") else "BBBB")
    assert_problem(anonymous.get("/v1/deployments", headers=bearer(forged)), 401)
    assert anonymous.get("/v1/deployments", headers=bearer(key)).status_code == 200


def test_only_the_hash_of_a_key_is_stored(engine: Engine, make_key: MakeKey) -> None:
    key = make_key("admin")
    with engine.connect() as connection:
        rows = connection.execute(text("SELECT * FROM api_key")).all()
    stored = [str(value) for row in rows for value in row]
    assert key_sha256(key) in stored
    assert not any(key in value or key.split("_", 2)[2] in value for value in stored)


def test_read_keys_read_and_run_jobs_but_change_nothing_else(
    anonymous: TestClient, make_key: MakeKey, world: dict[str, Any], paper_csv: str
) -> None:
    read = bearer(make_key("read"))
    batch = world["batch"]
    for path in (
        "/v1/deployments",
        f"/v1/deployments/{world['second']}",
        f"/v1/batches/{batch['id']}",
        "/v1/jobs",
        f"/v1/jobs/{batch['job']['id']}",
        "/v1/associators",
    ):
        assert anonymous.get(path, headers=read).status_code == 200, path
    job = anonymous.post("/v1/jobs", json={"batch_id": batch["id"]}, headers=read)
    assert job.status_code == 202, job.text
    forbidden = [
        ("POST", "/v1/deployments", {"json": {"name": "x"}}),
        (
            "POST",
            f"/v1/deployments/{world['first']}/batches",
            {"content": paper_csv, "headers": {"content-type": "text/csv"}},
        ),
        ("POST", "/v1/simulations", {"json": {"deployment_id": world["first"]}}),
        # Deleting data and managing webhooks (which send results out) are an admin's.
        ("DELETE", f"/v1/deployments/{world['first']}/batches/{batch['id']}", {}),
        ("DELETE", f"/v1/deployments/{world['second']}", {}),
        ("POST", f"/v1/deployments/{world['first']}/webhooks", {"json": {"url": "https://x.y"}}),
        ("GET", f"/v1/deployments/{world['first']}/webhooks", {}),
    ]
    for method, path, extra in forbidden:
        headers = {**extra.pop("headers", {}), **read}
        problem = assert_problem(anonymous.request(method, path, headers=headers, **extra), 403)
        assert "scope 'read'" in problem["detail"] and "'admin'" in problem["detail"]


def test_ingest_keys_post_and_read_their_own_deployments_only(
    anonymous: TestClient, make_key: MakeKey, world: dict[str, Any], paper_csv: str
) -> None:
    ingest = bearer(make_key("ingest", world["first"]))
    csv = {"content-type": "text/csv", **ingest}
    posted = anonymous.post(
        f"/v1/deployments/{world['first']}/batches?associator=kmeans",
        content=paper_csv,
        headers=csv,
    )
    assert posted.status_code == 201, posted.text
    job_id = posted.json()["job"]["id"]
    # ...and follows its own batch and job, as a gateway waiting for its association does.
    for path in (
        f"/v1/deployments/{world['first']}",
        f"/v1/batches/{posted.json()['id']}",
        f"/v1/jobs/{job_id}",
        "/v1/associators",
    ):
        assert anonymous.get(path, headers=ingest).status_code == 200, path
    assert_problem(anonymous.get(f"/v1/jobs/{job_id}/result", headers=ingest), 409)
    # Another deployment is out of bounds: posting, and reading what is in it.
    other = assert_problem(
        anonymous.post(
            f"/v1/deployments/{world['second']}/batches", content=paper_csv, headers=csv
        ),
        403,
    )
    assert world["second"] in other["detail"] and world["first"] in other["detail"]
    assert_problem(anonymous.get(f"/v1/deployments/{world['second']}", headers=ingest), 403)
    # Listing, creating deployments and starting jobs are not ingest work.
    for method, path, body in (
        ("GET", "/v1/deployments", None),
        ("GET", "/v1/jobs", None),
        ("POST", "/v1/jobs", {"batch_id": posted.json()["id"]}),
        ("POST", "/v1/deployments", {"name": "mine"}),
        ("DELETE", f"/v1/deployments/{world['first']}", None),
        ("GET", f"/v1/deployments/{world['first']}/webhooks", None),
    ):
        assert_problem(anonymous.request(method, path, json=body, headers=ingest), 403)


def test_a_read_key_cannot_read_another_deployments_batch_through_ingest_rules(
    anonymous: TestClient, make_key: MakeKey, world: dict[str, Any]
) -> None:
    """An ingest key of the second deployment may not see the first one's batch or job."""
    ingest = bearer(make_key("ingest", world["second"]))
    batch = world["batch"]
    assert_problem(anonymous.get(f"/v1/batches/{batch['id']}", headers=ingest), 403)
    assert_problem(anonymous.get(f"/v1/jobs/{batch['job']['id']}/result", headers=ingest), 403)
    assert_problem(anonymous.post(f"/v1/jobs/{batch['job']['id']}/cancel", headers=ingest), 403)


def test_a_revoked_key_is_401_from_then_on(
    anonymous: TestClient, database_url: str, make_key: MakeKey, monkeypatch: pytest.MonkeyPatch
) -> None:
    key = make_key("read")
    assert anonymous.get("/v1/associators", headers=bearer(key)).status_code == 200
    monkeypatch.setenv("ROADLINK_DATABASE_URL", database_url)
    prefix = key.split("_")[1]
    revoked = CliRunner().invoke(cli, ["keys", "revoke", prefix])
    assert revoked.exit_code == 0, revoked.output
    assert f"revoked read key {prefix}" in revoked.output
    response = anonymous.get("/v1/associators", headers=bearer(key))
    assert_problem(response, 401)
    assert 'error="invalid_token"' in response.headers["www-authenticate"]


def test_the_rate_limit_is_per_key_with_retry_after(
    settings: Settings, engine: Engine, make_key: MakeKey
) -> None:
    limited = settings.model_copy(update={"rate_limit_per_second": 0.5, "rate_limit_burst": 3})
    first, second = bearer(make_key("read")), bearer(make_key("read"))
    with TestClient(create_app(limited, engine=engine)) as http:
        answers = [http.get("/v1/associators", headers=first).status_code for _ in range(4)]
        assert answers == [200, 200, 200, 429]
        refused = http.get("/v1/associators", headers=first)
        problem = assert_problem(refused, 429)
        assert refused.headers["retry-after"] == "2"  # one token per 2 s
        assert "0.5 requests per second" in problem["detail"]
        # Another key has its own bucket; the health routes have none.
        assert http.get("/v1/associators", headers=second).status_code == 200
        assert all(http.get("/healthz").status_code == 200 for _ in range(5))


def test_auth_disabled_opens_every_route(
    settings: Settings, engine: Engine, paper_batch: Detections
) -> None:
    disabled = settings.model_copy(update={"auth": "disabled"})
    with TestClient(create_app(disabled, engine=engine)) as http:
        created = http.post("/v1/deployments", json={"name": "local"})
        assert created.status_code == 201, created.text
        posted = http.post(
            f"/v1/deployments/{created.json()['id']}/batches",
            content=write_detections_csv(paper_batch),
            headers={"content-type": "text/csv"},
        )
        assert posted.status_code == 201, posted.text


@pytest.mark.parametrize("host", ["0.0.0.0", "192.168.1.10", "::", "example.org"])
def test_serve_refuses_auth_disabled_off_loopback(
    host: str, monkeypatch: pytest.MonkeyPatch, tmp_path: Any
) -> None:
    monkeypatch.setenv("ROADLINK_AUTH", "disabled")
    monkeypatch.setenv("ROADLINK_DATABASE_URL", f"sqlite:///{tmp_path / 'never.db'}")
    result = CliRunner().invoke(cli, ["serve", "--host", host, "--workers", "0"])
    assert result.exit_code == 2
    assert "ROADLINK_AUTH=disabled" in result.output and host in result.output
    assert not (tmp_path / "never.db").exists(), "it refused before touching the database"
