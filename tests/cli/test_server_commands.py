"""The server-side commands read their settings from ROADLINK_* as documented."""

import os
import signal
import subprocess
import sys
import time

from typer.testing import CliRunner

from roadlink.cli import app
from roadlink.settings import Settings

runner = CliRunner()


def test_worker_takes_its_process_count_from_roadlink_workers(tmp_path):
    env = {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 'w.db'}", "ROADLINK_WORKERS": "0"}
    result = runner.invoke(app, ["worker"], env=env)
    assert result.exit_code == 2
    assert "ROADLINK_WORKERS" in result.stderr


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


def test_serve_drains_for_longer_than_the_longest_wait(tmp_path, monkeypatch):
    # uvicorn as `serve` configures it, for the default and a raised ROADLINK_MAX_WAIT_SECONDS.
    import uvicorn

    from roadlink.cli import server

    started: list[uvicorn.Config] = []
    monkeypatch.setattr(uvicorn, "run", lambda api, **kw: started.append(uvicorn.Config(api, **kw)))
    # What `serve` does to its own process, kept from the test's.
    monkeypatch.setattr(server, "_exit_on_sigterm", lambda: None)
    monkeypatch.setattr(server.gc, "freeze", lambda: None)
    monkeypatch.setattr(server.sys, "setswitchinterval", lambda seconds: None)
    for max_wait in (None, "300"):
        env = {"ROADLINK_DATABASE_URL": f"sqlite:///{tmp_path / 's.db'}", "ROADLINK_WORKERS": "0"}
        if max_wait:
            env["ROADLINK_MAX_WAIT_SECONDS"] = max_wait
        done = runner.invoke(app, ["serve"], env=env)
        assert done.exit_code == 0, done.output
        expected_wait = float(max_wait or Settings.model_fields["max_wait_seconds"].default)
        assert started[-1].timeout_graceful_shutdown is not None
        assert started[-1].timeout_graceful_shutdown > expected_wait
