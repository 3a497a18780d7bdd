"""The very commands the image runs, without a Docker engine.

The Dockerfile builds a wheel, installs it with the postgres extra into a clean interpreter and runs
`roadlink migrate | serve | worker`, probed by a python/urllib HEALTHCHECK. This test does the same
outside a container: `pip wheel --no-deps`, a fresh venv, the installed `roadlink` command, the
Dockerfile's own HEALTHCHECK command, and then (once the REST service provides those commands) the
compose topology against a fresh PostgreSQL database: migrate, an API without workers, a separate
worker process, a job run to completion through it.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
import uuid
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import httpx
import pytest

from roadlink.association import associate
from roadlink.simulation import preset, simulate
from tests.deploy.deploy_files import (
    MIGRATIONS_DIR,
    REPO_ROOT,
    assert_probe_tells_healthy_from_not,
    commands_in_help,
    read_dockerfile,
)
from tests.helpers import detection_rows

pytestmark = pytest.mark.slow

POSTGRES_ADMIN_URL = "postgresql://postgres@127.0.0.1:5432/test"


@dataclass(frozen=True)
class CleanInstall:
    """A venv holding only the built wheel (with the postgres extra) and its dependencies."""

    wheel: Path
    bin: Path

    @property
    def python(self) -> str:
        return str(self.bin / "python")

    @property
    def roadlink(self) -> str:
        return str(self.bin / "roadlink")


def clean_environment(**extra: str) -> dict[str, str]:
    """A minimal environment, so nothing of this test run's venv or settings leaks in."""
    environment = {
        key: os.environ[key] for key in ("PATH", "HOME", "LANG", "TMPDIR") if key in os.environ
    }
    environment.update(NO_COLOR="1", TERM="dumb", COLUMNS="120", **extra)
    return environment


def run(argv: list[str], timeout: float, **kwargs: Any) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        argv, capture_output=True, text=True, timeout=timeout, check=False, **kwargs
    )


@pytest.fixture(scope="module")
def clean_install(tmp_path_factory: pytest.TempPathFactory) -> CleanInstall:
    root = tmp_path_factory.mktemp("wheel-install")
    built = run(
        [sys.executable, "-m", "pip", "wheel", "--no-deps", "--quiet", "-w", str(root), "."],
        timeout=120,
        cwd=REPO_ROOT,
    )
    assert built.returncode == 0, built.stderr
    (wheel,) = root.glob("roadlink-*.whl")
    venv = root / "venv"
    made = run([sys.executable, "-m", "venv", str(venv)], timeout=60)
    assert made.returncode == 0, made.stderr
    # Dependencies come from the configured index and pip's cache, as in the image's build stage.
    installed = run(
        [str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", f"{wheel}[postgres]"],
        timeout=240,
    )
    assert installed.returncode == 0, installed.stderr
    return CleanInstall(wheel=wheel, bin=venv / "bin")


def installed_commands(clean_install: CleanInstall) -> set[str]:
    helped = run([clean_install.roadlink, "--help"], timeout=60, env=clean_environment())
    assert helped.returncode == 0, helped.stderr
    return commands_in_help(helped.stdout)


def test_wheel_carries_the_migrations_and_the_command(clean_install):
    with zipfile.ZipFile(clean_install.wheel) as wheel:
        names = set(wheel.namelist())
        (entry_points,) = [n for n in names if n.endswith(".dist-info/entry_points.txt")]
        assert "roadlink = roadlink.cli:main" in wheel.read(entry_points).decode()
    migrations = (
        sorted(
            path.relative_to(MIGRATIONS_DIR).as_posix()
            for path in MIGRATIONS_DIR.rglob("*")
            if path.is_file() and "__pycache__" not in path.parts
        )
        if MIGRATIONS_DIR.is_dir()
        else []
    )
    if not migrations:
        pytest.skip("migrations/ holds no files in this checkout yet (the REST service adds them)")
    missing = [m for m in migrations if f"roadlink/_migrations/{m}" not in names]
    assert not missing, f"pyproject's force-include left these out of the wheel: {missing}"


def test_installed_roadlink_command_runs_with_the_postgres_driver(clean_install):
    helped = run([clean_install.roadlink, "--help"], timeout=60, env=clean_environment())
    assert helped.returncode == 0, helped.stderr
    assert "Usage: roadlink" in helped.stdout
    assert {"simulate", "associate"} <= commands_in_help(helped.stdout)
    driver = run([clean_install.python, "-c", "import psycopg"], timeout=60)
    assert driver.returncode == 0, f"the postgres extra did not install psycopg: {driver.stderr}"


def test_dockerfile_healthcheck_command_tells_healthy_from_not(clean_install):
    (healthcheck,) = [i for i in read_dockerfile() if i.keyword == "HEALTHCHECK"]
    probe = healthcheck.exec_form()
    assert probe[0] == "python"
    # The image's `python` is the interpreter roadlink is installed in: the clean venv's here.
    argv = [clean_install.python, *probe[1:]]

    assert_probe_tells_healthy_from_not(
        "/healthz", lambda port: run(argv, timeout=30, env=clean_environment(ROADLINK_PORT=port))
    )


@pytest.fixture
def postgres_database() -> Iterator[str]:
    """A freshly created, uniquely named PostgreSQL database, dropped afterwards; its URL."""
    psycopg = pytest.importorskip("psycopg")
    try:
        admin = psycopg.connect(POSTGRES_ADMIN_URL, autocommit=True, connect_timeout=3)
    except psycopg.OperationalError as error:
        pytest.skip(f"PostgreSQL does not answer on 127.0.0.1:5432 ({error})")
    name = f"roadlink_deploy_{uuid.uuid4().hex[:12]}"
    with admin:
        admin.execute(f'CREATE DATABASE "{name}"')
        try:
            yield f"postgresql+psycopg://postgres@127.0.0.1:5432/{name}"
        finally:
            admin.execute(f'DROP DATABASE IF EXISTS "{name}" WITH (FORCE)')


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        port: int = probe.getsockname()[1]
        return port


def wait_for_http_200(
    url: str, processes: dict[str, subprocess.Popen[bytes]], limit: float
) -> None:
    """Poll a URL until it answers 200, failing early when one of the processes has exited."""
    deadline = time.monotonic() + limit
    last = "no answer"
    while time.monotonic() < deadline:
        for name, process in processes.items():
            assert process.poll() is None, f"`roadlink {name}` exited with {process.returncode}"
        try:
            answer = httpx.get(url, timeout=2)
            if answer.status_code == 200:
                return
            last = f"{answer.status_code} {answer.text[:200]}"
        except httpx.TransportError as error:
            last = repr(error)
        time.sleep(0.2)
    raise AssertionError(f"{url} did not answer 200 within {limit} s: {last}")


def identifier(resource: dict[str, Any], kind: str) -> str:
    """The id of a created resource (the API names path parameters `{kind}_id`)."""
    value = resource.get("id", resource.get(f"{kind}_id"))
    assert value is not None, f"no id in the created {kind}: {resource}"
    return str(value)


def test_migrate_serve_and_work_against_postgres(clean_install, request, tmp_path):
    missing = {"migrate", "serve", "worker"} - installed_commands(clean_install)
    if missing:
        pytest.skip(
            f"the installed roadlink has no {', '.join(sorted(missing))} command yet: "
            "migrate/serve/worker arrive with the REST service"
        )
    database_url = request.getfixturevalue("postgres_database")
    environment = clean_environment(ROADLINK_DATABASE_URL=database_url)

    migrated = run([clean_install.roadlink, "migrate"], timeout=120, env=environment)
    assert migrated.returncode == 0, migrated.stderr
    # Every /v1 route needs an API key; the first is made on the database, as the docs say.
    created = run(
        [clean_install.roadlink, "keys", "create", "--scope", "admin"], timeout=60, env=environment
    )
    assert created.returncode == 0, created.stderr
    key = created.stdout.strip()

    # The compose topology: an API that runs no jobs, and a separate worker process.
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    logs = {name: (tmp_path / f"{name}.log").open("wb") for name in ("serve", "worker")}
    commands = {
        "serve": [
            *(clean_install.roadlink, "serve", "--host", "127.0.0.1"),
            *("--port", str(port), "--workers", "0"),
        ],
        "worker": [clean_install.roadlink, "worker"],
    }
    processes = {
        name: subprocess.Popen(
            argv,
            env={**environment, "ROADLINK_WORKERS": "1"},
            stdout=logs[name],
            stderr=subprocess.STDOUT,
        )
        for name, argv in commands.items()
    }
    try:
        wait_for_http_200(f"{base}/healthz", processes, limit=45)
        assert httpx.get(f"{base}/readyz", timeout=5).status_code == 200

        detections = simulate(preset("small"), seed=11).detections
        rows = detection_rows(detections)
        with httpx.Client(
            base_url=base, headers={"Authorization": f"Bearer {key}"}, timeout=30
        ) as client:
            created = client.post("/v1/deployments", json={"name": "deploy-test"})
            assert created.status_code == 201, created.text
            deployment = identifier(created.json(), "deployment")
            posted = client.post(
                f"/v1/deployments/{deployment}/batches",
                json={"detections": rows, "associate": {"associator": "kmeans++"}},
            )
            assert posted.status_code == 201, posted.text
            job = identifier(posted.json()["job"], "job")
            # Only the separate worker process can run it: the API was started with --workers 0.
            result = client.get(f"/v1/jobs/{job}/result", params={"wait": 25}, timeout=40)
            assert result.status_code == 200, result.text
        expected = json.loads(json.dumps(associate(detections, "kmeans++").to_dict()))
        assert result.json()["n_detections"] == len(detections)
        assert result.json()["metrics"] == pytest.approx(expected["metrics"])
        for name, process in processes.items():
            assert process.poll() is None, f"`roadlink {name}` died during the job"
    finally:
        for process in processes.values():
            process.terminate()
        for name, process in processes.items():
            try:
                process.wait(timeout=20)
            except subprocess.TimeoutExpired:
                process.kill()
                process.wait()
            logs[name].close()
    for name, process in processes.items():
        log = (tmp_path / f"{name}.log").read_text(errors="replace")[-2000:]
        assert process.returncode in (0, -15), f"`roadlink {name}` stopped badly:\n{log}"
