"""`roadlink serve` and `roadlink worker` (`cli/server.py`): their settings read from ROADLINK_*
as documented, and stopping either stops its whole process tree (the workers and their associator
processes too, whether the signal is SIGTERM or Ctrl-C, and even when the parent is killed
outright; those tests are slow)."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import httpx
import pytest
from typer.testing import CliRunner

from roadlink.cli import app
from roadlink.queue.worker import PARENT_CHECK_SECONDS
from roadlink.settings import Settings
from tests.live_server import free_port, sqlite_env

runner = CliRunner()


def test_worker_takes_its_process_count_from_roadlink_workers(tmp_path):
    env = {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 'w.db'}", "ROADLINK_WORKERS": "0"}
    result = runner.invoke(app, ["worker"], env=env)
    assert result.exit_code == 2
    assert "needs at least one worker (ROADLINK_WORKERS)" in result.stderr


def test_worker_option_is_checked_and_the_error_names_it():
    result = runner.invoke(app, ["worker", "--workers", "0"])
    assert result.exit_code == 2
    assert "Invalid value for '--workers': 0 is not in the range x>=1" in result.stderr


def test_an_interrupt_while_the_workers_start_still_stops_them(tmp_path, monkeypatch):
    # Ctrl-C (or SIGTERM, made SystemExit) can land while the pool is still starting, after its
    # first worker runs: the pool must be stopped all the same, or this process waits forever
    # at exit for workers that live as long as it does (seen once in CI: `roadlink worker`
    # ignored a SIGINT sent the moment its second worker appeared).
    from roadlink.cli import server

    stopped = []

    def start_then_interrupted(pool):
        raise KeyboardInterrupt

    monkeypatch.setattr(server.WorkerPool, "start", start_then_interrupted)
    monkeypatch.setattr(server.WorkerPool, "stop", lambda pool: stopped.append(pool.size))
    env = {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 'w.db'}", "ROADLINK_WORKERS": "2"}
    runner.invoke(app, ["worker"], env=env)
    assert stopped == [2]


# Generous: a loaded two-core machine may take seconds to start or stop a Python process.
DEADLINE_SECONDS = 60.0


def _children(pid: int) -> set[int]:
    """Every live descendant of `pid` (from /proc)."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            try:
                fields = (entry / "stat").read_text().rsplit(")", 1)[1].split()
            except OSError:
                continue
            if fields[0] != "Z":
                parents[int(entry.name)] = int(fields[1])
    found, frontier = set(), {pid}
    while frontier:
        frontier = {child for child, parent in parents.items() if parent in frontier} - found
        found |= frontier
    return found


def _alive(pids: set[int]) -> set[int]:
    alive = set()
    for pid in pids:
        try:
            state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
        except OSError:
            continue
        if state != "Z":
            alive.add(pid)
    return alive


def _wait_for(condition, what: str) -> None:  # type: ignore[no-untyped-def]
    deadline = time.monotonic() + DEADLINE_SECONDS
    while not condition():
        assert time.monotonic() < deadline, what
        time.sleep(0.2)


def _start(command: list[str], tmp_path: Path) -> tuple[subprocess.Popen[bytes], str]:
    port = free_port()
    env = {**os.environ, **sqlite_env(tmp_path, ROADLINK_PORT=str(port), ROADLINK_WORKERS="2")}
    process = subprocess.Popen(
        [sys.executable, "-m", "roadlink.cli", *command],
        cwd=tmp_path,
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
        start_new_session=True,  # its own group, so the test's group is never signalled
    )
    return process, f"http://127.0.0.1:{port}"


def _workers(pids: set[int]) -> set[int]:
    """Those of `pids` that are worker processes (started by multiprocessing's spawn)."""
    found = set()
    for pid in pids:
        try:
            if b"spawn_main" in Path(f"/proc/{pid}/cmdline").read_bytes():
                found.add(pid)
        except OSError:
            continue
    return found


def _wait_for_workers(process: subprocess.Popen[bytes], count: int) -> set[int]:
    """The descendants, once `count` worker processes have started."""
    _wait_for(
        lambda: len(_workers(_children(process.pid))) >= count, f"{count} workers did not start"
    )
    return _children(process.pid)


@pytest.mark.slow  # starts a real worker process and waits for its first heartbeat
def test_worker_check_is_alive_while_a_worker_runs_and_not_once_it_stopped(tmp_path):
    database = f"sqlite:///{tmp_path / 'w.db'}"
    env = {
        "ROADLINK_DATABASE_URL": database,
        "ROADLINK_WORKER_HEARTBEAT_DIR": str(tmp_path / "heartbeats"),
        "ROADLINK_WORKERS": "1",
    }
    assert runner.invoke(app, ["migrate"], env=env).exit_code == 0
    nobody = runner.invoke(app, ["worker", "--check"], env=env)
    assert nobody.exit_code == 1 and "no worker heartbeat" in nobody.stderr
    worker = subprocess.Popen(
        [sys.executable, "-m", "roadlink.cli", "worker"], env={**os.environ, **env}
    )
    try:
        deadline = time.monotonic() + 60
        while runner.invoke(app, ["worker", "--check"], env=env).exit_code != 0:
            assert worker.poll() is None, "the worker exited"
            assert time.monotonic() < deadline, "no heartbeat from the running worker"
            time.sleep(0.2)
    finally:
        worker.send_signal(signal.SIGTERM)
        worker.wait(60)
    assert worker.returncode == 0
    assert runner.invoke(app, ["worker", "--check"], env=env).exit_code == 1


def serve_config(tmp_path, monkeypatch, **env: str):
    """uvicorn's configuration as `roadlink serve` sets it up with ROADLINK_* `env` (uvicorn
    not started; what `serve` does to its own process kept from the test's)."""
    import uvicorn

    from roadlink.cli import server

    started: list[uvicorn.Config] = []
    monkeypatch.setattr(uvicorn, "run", lambda api, **kw: started.append(uvicorn.Config(api, **kw)))
    monkeypatch.setattr(server, "_exit_on_sigterm", lambda: None)
    monkeypatch.setattr(server.gc, "freeze", lambda: None)
    monkeypatch.setattr(server.sys, "setswitchinterval", lambda seconds: None)
    env = {
        "ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 's.db'}",
        "ROADLINK_WORKERS": "0",
        **{f"ROADLINK_{name.upper()}": value for name, value in env.items()},
    }
    done = runner.invoke(app, ["serve"], env=env)
    assert done.exit_code == 0, done.output
    return started[-1]


def test_serve_drains_for_longer_than_the_longest_wait(tmp_path, monkeypatch):
    # For the default and a raised ROADLINK_MAX_WAIT_SECONDS.
    default = float(Settings.model_fields["max_wait_seconds"].default)
    for env, expected_wait in (({}, default), ({"max_wait_seconds": "300"}, 300.0)):
        config = serve_config(tmp_path, monkeypatch, **env)
        assert config.timeout_graceful_shutdown is not None
        assert config.timeout_graceful_shutdown > expected_wait


@pytest.mark.skipif(sys.platform == "win32", reason="httptools and uvloop are not installed there")
def test_serve_runs_on_the_c_http_parser_and_uvloop(tmp_path, monkeypatch):
    # Installed with roadlink (pyproject.toml), and taken by uvicorn as `serve` configures it:
    # both are the measured part of a small job's overhead that uvicorn itself adds.
    import asyncio

    from uvicorn.protocols.http.httptools_impl import HttpToolsProtocol

    config = serve_config(tmp_path, monkeypatch)
    config.load()
    assert config.http_protocol_class is HttpToolsProtocol
    loop_factory = config.get_loop_factory()
    assert loop_factory is not None
    loop = loop_factory()
    try:
        assert type(loop).__module__.startswith("uvloop")
        assert isinstance(loop, asyncio.AbstractEventLoop)
    finally:
        loop.close()


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_serve_stops_its_workers_with_it(tmp_path: Path, sig: signal.Signals) -> None:
    process, url = _start(["serve"], tmp_path)
    try:

        def ready() -> bool:
            try:
                return httpx.get(f"{url}/readyz", timeout=2).status_code == 200
            except httpx.TransportError:
                return False

        _wait_for(ready, "the server did not become ready")
        _signal_and_see_every_worker_stop(process, sig)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)


def _signal_and_see_every_worker_stop(
    process: subprocess.Popen[bytes], sig: signal.Signals
) -> None:
    """Once `process` has its two workers, send it `sig`; it and every descendant must stop."""
    tree = _wait_for_workers(process, 2)
    process.send_signal(sig)
    process.wait(DEADLINE_SECONDS)
    _wait_for(lambda: not _alive(tree), f"left running after {sig.name}: {_alive(tree)}")


def _start_worker(tmp_path: Path) -> subprocess.Popen[bytes]:
    """`roadlink worker` with two workers, on a migrated SQLite database in tmp_path."""
    subprocess.run(
        [sys.executable, "-m", "roadlink.cli", "migrate"],
        cwd=tmp_path,
        env={**os.environ, **sqlite_env(tmp_path)},
        check=True,
        capture_output=True,
    )
    return _start(["worker"], tmp_path)[0]


@pytest.mark.slow
@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_worker_stops_its_workers_with_it(tmp_path: Path, sig: signal.Signals) -> None:
    process = _start_worker(tmp_path)
    try:
        _signal_and_see_every_worker_stop(process, sig)
    finally:
        if process.poll() is None:
            os.killpg(process.pid, signal.SIGKILL)


@pytest.mark.slow
def test_workers_stop_by_themselves_when_serve_is_killed_outright(tmp_path: Path) -> None:
    process, _ = _start(["serve"], tmp_path)
    tree: set[int] = set()
    try:
        tree = _wait_for_workers(process, 2)
        process.kill()  # SIGKILL: no handler, no finally, nothing runs in the parent
        process.wait(DEADLINE_SECONDS)
        _wait_for(lambda: not _alive(tree), f"orphans left running: {_alive(tree)}")
    finally:
        for pid in _alive(tree):
            os.kill(pid, signal.SIGKILL)


@pytest.mark.slow
def test_a_worker_that_dies_is_replaced_by_one_that_stays(tmp_path: Path) -> None:
    process = _start_worker(tmp_path)
    try:
        first = _workers(_wait_for_workers(process, 2))
        os.kill(min(first), signal.SIGKILL)

        def replaced() -> set[int]:
            return _workers(_children(process.pid)) - first

        _wait_for(lambda: bool(replaced()), "no worker took the killed one's place")
        replacement = replaced()
        # Staying is the behaviour under test: a replacement told the wrong parent pid took
        # itself for an orphan at its first check (every PARENT_CHECK_SECONDS) and stopped, and
        # was replaced again, once a second.
        time.sleep(5 * PARENT_CHECK_SECONDS)
        assert _alive(replacement) == replacement
    finally:
        os.killpg(process.pid, signal.SIGKILL)
