"""compose.yaml: valid against the Compose Specification, and started in the order it promises.

No Docker engine runs on CI, so the file is checked against the Compose Specification JSON schema
(the copy check-jsonschema vendors from compose-spec/compose-spec, Apache-2.0), then for the
semantics a schema cannot see: start order gated on health, a worker service that scales, and
probes and commands that match what the roadlink image and command offer.
"""

from __future__ import annotations

import copy
import json
import os
import subprocess
import sys
import time
from importlib import resources
from typing import Any

import jsonschema
import pytest
from typer.testing import CliRunner

from roadlink.cli import app
from roadlink.cli.server import graceful_shutdown_seconds
from roadlink.settings import Settings
from tests.deploy.deploy_files import (
    OPENAPI_SPEC,
    REPO_ROOT,
    ROADLINK_SERVICES,
    assert_probe_tells_healthy_from_not,
    cli_commands,
    healthcheck_url,
    read_compose,
)


@pytest.fixture(scope="module")
def compose() -> dict[str, Any]:
    return read_compose()


@pytest.fixture(scope="module")
def compose_schema_validator() -> jsonschema.protocols.Validator:
    vendored = resources.files("check_jsonschema.builtin_schemas.vendor") / "compose-spec.json"
    schema = json.loads(vendored.read_text())
    validator_class = jsonschema.validators.validator_for(schema)
    validator_class.check_schema(schema)
    return validator_class(schema)


def schema_errors(validator: jsonschema.protocols.Validator, document: dict[str, Any]) -> list[str]:
    return [
        f"{'/'.join(map(str, error.absolute_path)) or '<root>'}: {error.message}"
        for error in validator.iter_errors(document)
    ]


def conditions(service: dict[str, Any]) -> dict[str, str]:
    depends_on = service.get("depends_on", {})
    assert isinstance(depends_on, dict), "use the long depends_on form, with a condition each"
    return {name: spec["condition"] for name, spec in depends_on.items()}


def test_compose_file_is_valid_against_the_compose_specification(compose, compose_schema_validator):
    assert schema_errors(compose_schema_validator, compose) == []


def test_schema_validation_rejects_what_compose_would_reject(compose, compose_schema_validator):
    # The schema check is only worth something if it catches mistakes: a misspelt condition and
    # an unknown service key.
    broken = copy.deepcopy(compose)
    broken["services"]["api"]["depends_on"]["migrate"]["condition"] = "service_completed"
    broken["services"]["worker"]["replica"] = 4
    errors = schema_errors(compose_schema_validator, broken)
    assert any("services/api/depends_on" in error for error in errors), errors
    assert any("replica" in error for error in errors), errors


def test_every_dependency_exists_and_waits_on_health_or_completion(compose):
    services = compose["services"]
    for name, service in services.items():
        for dependency, condition in conditions(service).items():
            assert dependency in services, f"{name} depends on an undefined service {dependency}"
            assert condition in {"service_healthy", "service_completed_successfully"}, (
                f"{name} starts on {dependency}'s mere start ({condition}); gate it on health"
            )
            if condition == "service_healthy":
                healthcheck = services[dependency].get("healthcheck", {})
                assert healthcheck.get("test") and not healthcheck.get("disable"), (
                    f"{name} waits for {dependency} to be healthy, but it has no healthcheck"
                )


def test_start_order_is_db_then_migrate_then_api_and_workers(compose):
    services = compose["services"]
    assert conditions(services["db"]) == {}
    assert conditions(services["migrate"]) == {"db": "service_healthy"}
    for name in ("api", "worker"):
        assert conditions(services[name]) == {
            "db": "service_healthy",
            "migrate": "service_completed_successfully",
        }


def test_database_is_postgres_15_checked_with_pg_isready_on_a_named_volume(compose):
    db = compose["services"]["db"]
    assert db["image"].split(":")[0] == "postgres" and db["image"].split(":")[1].startswith("15")
    assert db["healthcheck"]["test"][0] == "CMD-SHELL"
    assert "pg_isready" in db["healthcheck"]["test"][1]
    volume, _, target = db["volumes"][0].partition(":")
    assert volume in compose["volumes"] and target == "/var/lib/postgresql/data"


def test_migrate_runs_once(compose):
    migrate = compose["services"]["migrate"]
    assert migrate["command"] == ["migrate"]
    assert migrate["restart"] == "no"


def test_worker_service_scales(compose):
    worker = compose["services"]["worker"]
    # A fixed container name or a published host port makes `--scale worker=N` fail for N > 1.
    assert "container_name" not in worker
    assert "ports" not in worker
    assert worker["command"] == ["worker"]
    # One worker process per container: `--scale worker=N` then means N workers.
    assert worker["environment"]["ROADLINK_WORKERS"] == "1"


def test_services_without_http_do_not_inherit_the_images_healthz_probe(compose):
    # The image's HEALTHCHECK probes /healthz; a worker or the migrate step serves no HTTP, so the
    # inherited probe would mark them unhealthy forever.
    assert compose["services"]["migrate"]["healthcheck"] == {"disable": True}
    assert compose["services"]["worker"]["healthcheck"]["test"] == [
        "CMD",
        "roadlink",
        "worker",
        "--check",
    ]


@pytest.mark.parametrize("age_seconds, exit_code", [(0, 0), (3600, 1)])
def test_the_workers_probe_tells_a_heartbeating_worker_from_a_stale_one(
    compose, tmp_path, age_seconds, exit_code
):
    # The probe's own argv, run as the container runs it (a file as a worker leaves it: see
    # tests/cli/test_server.py for a real worker).
    probe = compose["services"]["worker"]["healthcheck"]["test"]
    heartbeat = tmp_path / "worker-7"
    heartbeat.touch()
    then = time.time() - age_seconds
    os.utime(heartbeat, (then, then))
    env = {"ROADLINK_WORKER_HEARTBEAT_DIR": str(tmp_path)}
    assert CliRunner().invoke(app, probe[2:], env=env).exit_code == exit_code


def test_every_roadlink_setting_can_come_from_the_env_file(compose):
    for name in ROADLINK_SERVICES:
        service = compose["services"][name]
        assert service["env_file"] == [{"path": ".env", "required": False}]
        # `environment` wins over the env file: only what compose must own is pinned there.
        pinned = {k for k in service["environment"] if k.startswith("ROADLINK_")}
        assert pinned <= {"ROADLINK_DATABASE_URL", "ROADLINK_PORT", "ROADLINK_WORKERS"}
    assert ".env" in (REPO_ROOT / ".dockerignore").read_text().split(), "a .env holds secrets"


def test_stopping_the_api_waits_for_its_longest_request(compose):
    grace = compose["services"]["api"]["stop_grace_period"]
    assert grace.endswith("s")
    assert float(grace[:-1]) > graceful_shutdown_seconds(Settings())


def test_the_api_probe_tells_ready_from_not(compose):
    # The probe's own argv, with the port from ROADLINK_PORT as in the container.
    argv = [sys.executable, *compose["services"]["api"]["healthcheck"]["test"][2:]]

    def probe(port: str) -> subprocess.CompletedProcess[str]:
        env = {**os.environ, "ROADLINK_PORT": port}
        return subprocess.run(argv, env=env, capture_output=True, text=True, timeout=30)

    assert_probe_tells_healthy_from_not("/readyz", probe)


def test_api_answers_http_only_and_probes_readyz_on_its_port(compose):
    api = compose["services"]["api"]
    command = api["command"]
    assert command[0] == "serve"
    assert command[command.index("--workers") + 1] == "0", "jobs run in the worker service"
    port = command[command.index("--port") + 1]
    assert api["environment"]["ROADLINK_PORT"] == port
    assert [published.rsplit(":", 1)[1] for published in api["ports"]] == [port]
    probe = api["healthcheck"]["test"]
    assert probe[0] == "CMD"
    assert healthcheck_url(probe[1:], api["environment"]) == f"http://127.0.0.1:{port}/readyz"


def test_roadlink_services_share_the_image_and_the_postgres_database(compose):
    services = compose["services"]
    images = {services[name]["image"] for name in ROADLINK_SERVICES}
    assert len(images) == 1
    db_environment = services["db"]["environment"]
    for name in ROADLINK_SERVICES:
        assert services[name]["build"]["target"] == "runtime"
        url = services[name]["environment"]["ROADLINK_DATABASE_URL"]
        assert url.startswith("postgresql+psycopg://"), f"{name} is not on PostgreSQL: {url}"
        assert "@db:5432/" in url, f"{name} does not reach the db service: {url}"
        # The credentials are the same interpolations the db service is created with.
        for key in ("POSTGRES_USER", "POSTGRES_PASSWORD", "POSTGRES_DB"):
            assert db_environment[key] in url, f"{name}'s URL does not use {key}"


def test_every_named_volume_is_declared(compose):
    declared = set(compose.get("volumes") or {})
    for name, service in compose["services"].items():
        for volume in service.get("volumes", []):
            source = volume.partition(":")[0]
            if not source.startswith((".", "/", "~")):
                assert source in declared, f"{name} mounts undeclared volume {source}"


def test_the_probed_paths_are_paths_of_the_app():
    if not OPENAPI_SPEC.exists():
        pytest.skip("openapi/openapi.json is not in this checkout yet (the REST service lands it)")
    paths = json.loads(OPENAPI_SPEC.read_text())["paths"]
    assert "/healthz" in paths, "the image probes /healthz; the app must serve it"
    assert "/readyz" in paths, "compose.yaml's api probes /readyz; the app must serve it"


def test_the_commands_compose_runs_exist_in_roadlink():
    needed = {"migrate", "serve", "worker"}
    missing = needed - cli_commands()
    if missing:
        pytest.skip(
            f"`roadlink --help` does not list {', '.join(sorted(missing))} yet "
            "(the REST service adds them)"
        )
    serve_help = CliRunner().invoke(app, ["serve", "--help"]).output
    for option in ("--host", "--port", "--workers"):
        assert option in serve_help, f"compose.yaml runs `serve {option} ...`; serve lacks it"
