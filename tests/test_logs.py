"""ROADLINK_LOG_FORMAT=json: each record one JSON object carrying the ids of what it is about,
from the API (its access log included) and the workers; read back here as the lines they are."""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import pytest

from roadlink.db.engine import make_session_factory
from roadlink.logs import ContextFilter, JsonFormatter, configure_logging, log_context
from roadlink.queue.webhook_dispatch import WebhookDispatcher
from roadlink.settings import Settings
from tests.helpers import post_csv_batch
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env

CSV = "position,velocity,timestamp\n0,30,1\n100,30,4.3\n0,20,2\n100,20,7\n"


@pytest.fixture
def json_lines() -> Iterator[io.StringIO]:
    """What the root logger writes, as ROADLINK_LOG_FORMAT=json writes it."""
    stream = io.StringIO()
    handler = logging.StreamHandler(stream)
    handler.addFilter(ContextFilter())
    handler.setFormatter(JsonFormatter())
    root = logging.getLogger()
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    yield stream
    root.removeHandler(handler)
    root.setLevel(level)


def parsed(stream: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in stream.getvalue().splitlines()]


def test_a_line_has_time_level_logger_message_and_the_ids_in_context(json_lines):
    log = logging.getLogger("roadlink.test")
    with log_context(request_id="r-1", job_id="j-1"):
        log.warning("job %s: %d", "j-1", 3)
        with log_context(batch_id="b-1"):
            log.info("inner", extra={"job_id": "given"})
    log.error("outside")
    first, inner, outside = parsed(json_lines)
    assert first["timestamp"].endswith("+00:00") and "T" in first["timestamp"]
    assert first["level"] == "warning" and first["logger"] == "roadlink.test"
    assert first["message"] == "job j-1: 3"
    assert (first["request_id"], first["job_id"]) == ("r-1", "j-1")
    assert "batch_id" not in first and "deployment_id" not in first
    assert (inner["batch_id"], inner["job_id"]) == ("b-1", "given")
    assert not {"request_id", "job_id", "batch_id"} & outside.keys()


def test_a_traceback_is_one_field_of_the_line(json_lines):
    try:
        raise ValueError("bad")
    except ValueError:
        logging.getLogger("roadlink.test").exception("failed")
    (line,) = parsed(json_lines)
    assert "ValueError: bad" in line["exception"] and line["message"] == "failed"


def test_configure_logging_writes_json_or_text_once(capsys):
    log = logging.getLogger("roadlink.test")
    root = logging.getLogger()
    handlers, level = list(root.handlers), root.level
    try:
        for _ in range(2):  # again: still one handler, one line per record
            configure_logging(Settings(log_format="json", database_url="sqlite://"))
        log.info("hello")
        configure_logging(Settings(log_format="text", database_url="sqlite://"))
        log.info("plain")
    finally:
        for handler in list(root.handlers):
            root.removeHandler(handler)
        for handler in handlers:
            root.addHandler(handler)
        root.setLevel(level)
    lines = capsys.readouterr().err.splitlines()
    assert len(lines) == 2
    assert json.loads(lines[0])["message"] == "hello"
    assert lines[1].endswith(" INFO plain")


def test_a_workers_lines_for_a_job_carry_the_id_of_the_request_that_made_it(
    client, deployment, worker, json_lines
):
    created = post_csv_batch(
        client, deployment["id"], CSV, associator="kmeans", request_id="gw7-0042"
    )
    json_lines.truncate(0)
    json_lines.seek(0)
    assert worker.run_once()
    lines = [line for line in parsed(json_lines) if line["logger"] == "roadlink.queue.worker"]
    assert [line["message"].split(" ", 2)[2] for line in lines] == [
        "claimed (attempt 1 of 3)",
        lines[1]["message"].split(" ", 2)[2],
    ]
    assert "succeeded" in lines[1]["message"]
    for line in lines:
        assert line["request_id"] == "gw7-0042"
        assert line["job_id"] == created["job"]["id"]
        assert line["deployment_id"] == deployment["id"]
        assert line["batch_id"] == created["id"]


def test_the_audit_line_of_a_delete_carries_the_request_deployment_and_batch(
    client, deployment, json_lines
):
    batch = post_csv_batch(client, deployment["id"], CSV)
    path = f"/v1/deployments/{deployment['id']}/batches/{batch['id']}"
    deleted = client.delete(path, headers={"X-Request-ID": "ops-7"})
    assert deleted.status_code == 204, deleted.text
    [line] = [line for line in parsed(json_lines) if line["logger"] == "roadlink.audit"]
    assert (line["request_id"], line["deployment_id"]) == ("ops-7", deployment["id"])
    assert line["batch_id"] == batch["id"]


def test_a_webhook_delivery_line_carries_the_deployment_job_and_the_jobs_request(
    client, deployment, worker, engine, settings, json_lines
):
    hooks = f"/v1/deployments/{deployment['id']}/webhooks"
    # Nothing listens on the discard port: the attempt fails at once, and is logged.
    assert client.post(hooks, json={"url": "http://127.0.0.1:9/"}).status_code == 201
    created = post_csv_batch(
        client, deployment["id"], CSV, associator="kmeans", request_id="gw7-0043"
    )
    assert worker.run_once()
    dispatcher = WebhookDispatcher(settings, make_session_factory(engine))
    try:
        assert dispatcher.dispatch_once()
    finally:
        dispatcher.close()
    [line] = [
        line for line in parsed(json_lines) if line["logger"] == "roadlink.queue.webhook_dispatch"
    ]
    assert line["message"].startswith("webhook delivery ")
    assert (line["request_id"], line["job_id"]) == ("gw7-0043", created["job"]["id"])
    assert line["deployment_id"] == deployment["id"]


@pytest.mark.slow
def test_a_live_server_logs_json_lines_from_api_access_log_and_worker(tmp_path: Path) -> None:
    # A long wait allowed: on a loaded machine the worker process may take a while to start.
    env = sqlite_env(
        tmp_path,
        ROADLINK_LOG_FORMAT="json",
        ROADLINK_LOG_LEVEL="info",
        ROADLINK_MAX_WAIT_SECONDS="240",
    )
    live = LiveServer(tmp_path, env, free_port())
    key = roadlink("keys", "create", "--scope", "admin", env=env, cwd=tmp_path).strip()
    live.start(workers=1)
    try:
        auth = {"Authorization": f"Bearer {key}"}
        with httpx.Client(base_url=live.url, headers=auth, timeout=300) as http:
            deployment = http.post("/v1/deployments", json={"name": "logged"}).json()["id"]
            batch = post_csv_batch(http, deployment, CSV, associator="kmeans")
            job = batch["job"]["id"]
            waited = http.get(
                f"/v1/jobs/{job}/result", params={"wait": 240}, headers={"X-Request-ID": "wait-1"}
            )
            assert waited.status_code == 200, waited.text
            created_by = batch["job"]["request_id"]
    finally:
        live.stop()
    lines = [json.loads(line) for line in (tmp_path / "serve.log").read_text().splitlines()]
    access = [line for line in lines if line["logger"] == "uvicorn.access"]
    (wait,) = [line for line in access if line.get("request_id") == "wait-1"]
    assert wait["path"] == f"/v1/jobs/{job}/result?wait=240" and wait["status"] == 200
    assert wait["job_id"] == job and wait["method"] == "GET"
    (post,) = [line for line in access if line.get("request_id") == created_by]
    assert post["deployment_id"] == deployment and post["status"] == 201
    worker = [line for line in lines if line["logger"] == "roadlink.queue.worker"]
    for_job = [line for line in worker if line.get("job_id") == job]
    assert any("succeeded" in line["message"] for line in for_job)
    assert {line["request_id"] for line in for_job} == {created_by}
    assert all(line["process"] != access[0]["process"] for line in for_job)
