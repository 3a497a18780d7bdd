"""The server-side commands read their settings from ROADLINK_* as documented."""

from typer.testing import CliRunner

from roadlink.cli import app

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
