"""The job page at /jobs/{id}, in process: who may see it (signed page links, bearer keys, the
auth switch), what it shows in each state, and that what it shows is escaped."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime, timedelta
from html.parser import HTMLParser
from typing import Any
from urllib.parse import parse_qs, urlsplit

import pytest
from fastapi.testclient import TestClient
from sqlalchemy import Engine, update

from roadlink.api import create_app
from roadlink.api.pagelinks import token_key
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.detections import Detections
from roadlink.db.apikeys import find_api_key, revoke_api_key
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.models import Job
from roadlink.queue.worker import Worker
from roadlink.settings import Settings
from tests.helpers import COMMITTED_DENSE, MakeKey, bearer, one_sensor_in_km_per_hour


class Page(HTMLParser):
    """The parts of a page the tests look at: element ids, meta refresh, text."""

    def __init__(self, html: str) -> None:
        super().__init__()
        self.ids: dict[str, str] = {}
        self.refresh: str | None = None
        self.text: list[str] = []
        self.target_rows = 0
        self.feed(html)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        a = dict(attrs)
        if a.get("id"):
            self.ids[str(a["id"])] = tag
        if tag == "meta" and a.get("http-equiv") == "refresh":
            self.refresh = a.get("content")
        if tag == "tr" and a.get("class") == "target":
            self.target_rows += 1

    def handle_data(self, data: str) -> None:
        self.text.append(data)


def _post(client: TestClient, deployment_id: str, text: str, associator: str = "kmeans++") -> str:
    posted = client.post(
        f"/v1/deployments/{deployment_id}/batches",
        content=text,
        headers={"content-type": "text/csv"},
        params={"associator": associator},
    )
    assert posted.status_code == 201, posted.text
    return str(posted.json()["job"]["id"])


def _link(client: TestClient, job_id: str, **headers: str) -> str:
    made = client.post(f"/v1/jobs/{job_id}/page-link", headers=headers)
    assert made.status_code == 201, made.text
    return str(made.json()["url"])


@pytest.fixture
def anonymous(client: TestClient) -> TestClient:
    """The same app, as a browser: no Authorization header."""
    return TestClient(client.app)


@pytest.mark.slow
def test_a_page_link_opens_a_finished_jobs_page_without_a_key(
    client: TestClient,
    anonymous: TestClient,
    worker: Worker,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    job = _post(client, deployment["id"], paper_csv)
    assert worker.run_once()
    made = client.post(f"/v1/jobs/{job}/page-link", params={"expires_in": 600})
    assert made.status_code == 201, made.text
    expires = datetime.fromisoformat(made.json()["expires_at"])
    assert timedelta(seconds=590) < expires - datetime.now(UTC) <= timedelta(seconds=600)
    url = urlsplit(made.json()["url"])
    assert url.path == f"/jobs/{job}" and parse_qs(url.query)["token"]

    response = anonymous.get(f"{url.path}?{url.query}")
    assert response.status_code == 200, response.text
    assert response.headers["content-type"].startswith("text/html")
    assert "script-src" not in response.headers["content-security-policy"]
    assert "default-src 'none'" in response.headers["content-security-policy"]
    assert response.headers["referrer-policy"] == "no-referrer"
    assert response.headers["cache-control"] == "no-store"
    page = Page(response.text)
    assert page.refresh is None  # finished: nothing to wait for
    assert page.ids["plot"] == "figure" and "<svg" in response.text
    assert 'id="target-T1"' in response.text
    result = client.get(f"/v1/jobs/{job}/result").json()
    assert page.target_rows == result["n_targets"]
    assert page.ids["metrics"] == "table" and page.ids["targets"] == "table"
    assert f"{result['metrics']['accuracy']:.1%}" in "".join(page.text)
    # Every detection is listed under its target.
    for target in result["targets"]:
        for detection in target["detections"]:
            assert f">{detection['detection_id']}<" in response.text
    # The other plot, with the token kept in the link.
    other = anonymous.get(
        url.path, params={"kind": "backprojected", "token": parse_qs(url.query)["token"][0]}
    )
    assert other.status_code == 200 and "back-projected" in other.text.lower()
    assert 'href="?kind=time-space&amp;token=' in other.text


def test_an_unfinished_job_refreshes_itself_and_a_failed_one_shows_its_error_escaped(
    client: TestClient,
    anonymous: TestClient,
    deployment: dict[str, Any],
    paper_csv: str,
    engine: Engine,
) -> None:
    job = _post(client, deployment["id"], paper_csv)
    page = client.get(f"/jobs/{job}")  # the client's bearer key works too
    assert page.status_code == 200, page.text
    parsed = Page(page.text)
    assert parsed.refresh == "2"
    assert parsed.ids["state"] and parsed.ids["progress"] == "div" and "plot" not in parsed.ids
    assert "queued" in "".join(parsed.text)

    hostile = '<script>alert("x")</script> & <img src=x onerror=alert(1)>'
    with transaction(make_session_factory(engine)) as session:
        session.execute(
            update(Job).where(Job.id == uuid.UUID(job)).values(state="failed", error=hostile)
        )
    failed = client.get(f"/jobs/{job}")
    parsed = Page(failed.text)
    assert parsed.refresh is None and parsed.ids["error"] == "pre"
    assert hostile in "".join(parsed.text)  # shown as text...
    assert "<script>" not in failed.text and "<img src=x" not in failed.text  # ...never as markup


def test_who_may_see_a_page(
    client: TestClient,
    anonymous: TestClient,
    engine: Engine,
    make_key: MakeKey,
    deployment: dict[str, Any],
    paper_csv: str,
) -> None:
    job = _post(client, deployment["id"], paper_csv)
    other_job = _post(client, deployment["id"], paper_csv)
    # No key, no link: 401 with a page that says how to get one.
    denied = anonymous.get(f"/jobs/{job}")
    assert denied.status_code == 401 and "page-link" in denied.text
    assert denied.headers["content-type"].startswith("text/html")
    # A link opens its own job only, and not once tampered with.
    url = urlsplit(_link(client, job))
    token = parse_qs(url.query)["token"][0]
    assert anonymous.get(f"/jobs/{job}", params={"token": token}).status_code == 200
    assert anonymous.get(f"/jobs/{other_job}", params={"token": token}).status_code == 401
    prefix, expires, signature = token.split(".")
    for forged in (
        f"{prefix}.{int(expires) + 3600}.{signature}",
        f"{prefix}.{expires}.{signature[:-2]}AA",
        f"{prefix}.{expires}",
        f"{prefix}.\u00b2.{signature}",  # '²'.isdigit() is True; int('²') fails
        f"{prefix}.\u0663\u0660.{signature}",  # Arabic-Indic digits: int() reads 30
        f"{prefix}.{int(expires):_}.{signature}",  # int() reads underscores
        f"{prefix}. {expires}.{signature}",
        "garbage",
        "",
    ):
        assert anonymous.get(f"/jobs/{job}", params={"token": forged}).status_code == 401, forged
    # Expired: checked against the clock.
    with make_session_factory(engine)() as session:
        assert token_key(session, token=token, job_id=uuid.UUID(job)) is not None
        later = datetime.fromtimestamp(int(expires) + 1, UTC)
        assert token_key(session, token=token, job_id=uuid.UUID(job), now=later) is None
    # Keys: an ingest key of the job's deployment may make a link; one of another may not, nor
    # see the page with its bearer key; a revoked key's links die with it.
    own = make_key("ingest", deployment["id"])
    other_deployment = client.post("/v1/deployments", json={"name": "elsewhere"}).json()["id"]
    foreign = make_key("ingest", other_deployment)
    own_link = urlsplit(_link(anonymous, job, **bearer(own)))
    assert anonymous.get(f"{own_link.path}?{own_link.query}").status_code == 200
    refused = anonymous.post(f"/v1/jobs/{job}/page-link", headers=bearer(foreign))
    assert refused.status_code == 403
    assert anonymous.get(f"/jobs/{job}", headers=bearer(foreign)).status_code == 403
    assert anonymous.post(f"/v1/jobs/{job}/page-link").status_code == 401
    with transaction(make_session_factory(engine)) as session:
        row = find_api_key(session, reference=own.split("_")[1])
        assert row is not None and revoke_api_key(session, key_id=row.id)
    assert anonymous.get(f"{own_link.path}?{own_link.query}").status_code == 401
    # Unknown jobs, and ids that are not ids.
    assert client.get(f"/jobs/{uuid.uuid4()}").status_code == 404
    assert client.get("/jobs/../etc/passwd").status_code == 404
    assert client.get("/jobs/not-a-job").status_code == 404
    assert client.post(f"/v1/jobs/{uuid.uuid4()}/page-link").status_code == 404


def test_with_authentication_disabled_pages_need_no_token(
    settings: Settings, engine: Engine, deployment: dict[str, Any], paper_csv: str
) -> None:
    disabled = settings.model_copy(update={"auth": "disabled"})
    with TestClient(create_app(disabled, engine=engine)) as http:
        job = _post(http, deployment["id"], paper_csv)
        made = http.post(f"/v1/jobs/{job}/page-link").json()
        assert made["expires_at"] is None and urlsplit(made["url"]).query == ""
        assert http.get(f"/jobs/{job}").status_code == 200


def test_the_page_is_not_in_the_api_schema(client: TestClient) -> None:
    paths = client.get("/openapi.json").json()["paths"]
    assert not [p for p in paths if p.startswith("/jobs")]


def test_a_page_link_never_points_at_the_host_the_client_named(
    settings: Settings, engine: Engine, admin_key: str, deployment: dict[str, Any], paper_csv: str
) -> None:
    """The link carries a token: built from the request's Host header, a forged Host would send
    it to the attacker's server. It is relative, or under ROADLINK_PUBLIC_URL."""
    from roadlink.api import create_app

    auth = {"Authorization": f"Bearer {admin_key}"}
    for public_url, expected in [
        (None, "/jobs/"),
        ("https://roadlink.example/traffic/", "https://roadlink.example/traffic/jobs/"),
    ]:
        app = create_app(settings.model_copy(update={"public_url": public_url}), engine=engine)
        with TestClient(app, headers=auth) as http:
            job = _post(http, deployment["id"], paper_csv)
            made = http.post(f"/v1/jobs/{job}/page-link", headers={"Host": "evil.example"})
            assert made.status_code == 201, made.text
            url = made.json()["url"]
            assert url.startswith(f"{expected}{job}?token=") and "evil" not in url


@pytest.mark.parametrize("associator", ["assignment", "kmeans++"])
def test_the_page_shows_confidences_where_the_associator_gives_them(
    client: TestClient, worker: Worker, deployment: dict[str, Any], paper_csv: str, associator: str
) -> None:
    job = _post(client, deployment["id"], paper_csv, associator)
    assert worker.run_once()
    page = client.get(f"/jobs/{job}")
    assert page.status_code == 200, page.text
    result = client.get(f"/v1/jobs/{job}/result").json()
    if associator == "kmeans++":
        assert ">Confidence</th>" not in page.text
        return
    assert ">Confidence</th>" in page.text and ">Link</th>" in page.text
    first = result["targets"][0]
    assert f"{100 * first['confidence']:.0f} %" in page.text
    assert f"{100 * first['detections'][1]['link_confidence']:.0f} %" in page.text


def dense() -> Detections:
    return read_detections_csv(COMMITTED_DENSE)


def test_the_page_and_the_result_say_what_is_wrong_with_the_detectors(
    client: TestClient, worker: Worker, deployment: dict[str, Any]
) -> None:
    """One sensor sends km/h among sensors in m/s: the result names it in `warnings`, and the
    job page lists it under Detectors; a job with nothing wrong has neither."""
    for detections, warned in ((one_sensor_in_km_per_hour(5), True), (dense(), False)):
        job = _post(
            client, deployment["id"], write_detections_csv(detections), associator="assignment"
        )
        assert worker.run_once()
        result = client.get(f"/v1/jobs/{job}/result").json()
        parsed = Page(client.get(f"/jobs/{job}").text)
        if warned:
            (warning,) = result["warnings"]
            assert warning.startswith("the sensor at position 1450 reads speeds about 3.")
            assert parsed.ids["warnings"] == "ul" and warning in "".join(parsed.text)
        else:
            assert "warnings" not in result and "warnings" not in parsed.ids
