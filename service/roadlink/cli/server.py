"""Commands that run the service: serve, worker, migrate, openapi."""

from __future__ import annotations

import gc
import logging
import math
import multiprocessing
import multiprocessing.process
import os
import signal
import sys
import threading
import time
from pathlib import Path
from typing import TYPE_CHECKING, Annotated, Any

import typer

from roadlink.cli.root import app
from roadlink.logs import configure_logging

if TYPE_CHECKING:
    # Imported where a command runs: pydantic-settings costs every command's start 0.05 s.
    from roadlink.settings import Settings

log = logging.getLogger("roadlink")

# Beyond the longest `?wait=`: time for the answer itself once the wait ends.
GRACEFUL_SHUTDOWN_MARGIN_SECONDS = 5.0

# Python's default is 5 ms (see `serve_command`).
API_SWITCH_INTERVAL_SECONDS = 0.001

# Spawned, not forked: a worker must not inherit the API's threads, sockets or connections.
_spawn = multiprocessing.get_context("spawn")


def _settings(**overrides: object) -> Settings:
    from roadlink.settings import Settings

    given = {k: v for k, v in overrides.items() if v is not None}
    try:
        return Settings(**given)  # type: ignore[arg-type]
    except Exception as exc:
        typer.echo(f"error: invalid configuration: {exc}", err=True)
        raise typer.Exit(code=2) from None


class WorkerPool:
    """N worker processes, restarted if one dies, stopped together: the one owner of the
    process tree under `serve` and `worker` (each worker also stops by itself if this process
    dies without stopping it, see `roadlink.queue.worker.run_worker_process`)."""

    def __init__(self, settings: Settings, size: int) -> None:
        self.settings = settings
        self.size = size
        self.processes: list[multiprocessing.process.BaseProcess] = []
        self._stopping = threading.Event()
        self._watcher = threading.Thread(target=self._watch, daemon=True)

    def start(self) -> None:
        from roadlink.queue.worker import run_worker_process

        for _ in range(self.size):
            process = _spawn.Process(target=run_worker_process, args=(self.settings, os.getpid()))
            process.start()
            self.processes.append(process)
        self._watcher.start()

    def _watch(self) -> None:
        from roadlink.queue.worker import run_worker_process

        while not self._stopping.wait(1.0):
            for k, process in enumerate(self.processes):
                if not process.is_alive() and not self._stopping.is_set():
                    log.warning(
                        "worker %s exited (%s); starting another", process.pid, process.exitcode
                    )
                    replacement = _spawn.Process(
                        target=run_worker_process, args=(self.settings, os.getpid())
                    )
                    replacement.start()
                    self.processes[k] = replacement

    def stop(self, grace_seconds: float = 10.0) -> None:
        """SIGTERM every worker (each hands its job back), then SIGKILL what is left."""
        self._stopping.set()
        for process in self.processes:
            if process.is_alive():
                process.terminate()
        deadline = time.monotonic() + grace_seconds
        for process in self.processes:
            process.join(max(deadline - time.monotonic(), 0.1))
            if process.is_alive():
                process.kill()
                process.join()

    def join(self) -> None:
        for process in self.processes:
            process.join()


def _exit_on_sigterm() -> None:
    """Make SIGTERM end this process through `finally` blocks, as Ctrl-C does.

    Python's default SIGTERM kills the process on the spot, so a `finally: pool.stop()` never
    runs and the worker processes live on, re-parented to PID 1. uvicorn makes this matter for
    `serve`: it handles SIGTERM itself, shuts down gracefully, then restores the previous handler
    and raises the signal again, which, left at the default, is that on-the-spot kill.
    """

    def leave(_signum: int, _frame: object) -> None:
        raise SystemExit(0)  # a stop that was asked for, and done, is a success

    signal.signal(signal.SIGTERM, leave)


def _migrate(settings: Settings) -> None:
    from roadlink.db.migrate import upgrade_to_head

    upgrade_to_head(settings.database_url)
    # Readiness checks read the revision on every probe; alembic would log each one.
    logging.getLogger("alembic").setLevel(logging.WARNING)


@app.command("serve")
def serve_command(
    host: Annotated[str | None, typer.Option(help="Address to listen on [ROADLINK_HOST].")] = None,
    port: Annotated[int | None, typer.Option(help="Port to listen on [ROADLINK_PORT].")] = None,
    workers: Annotated[
        int | None,
        typer.Option(help="Worker processes (0 = API only) [ROADLINK_WORKERS; default: cores]."),
    ] = None,
) -> None:
    """Run the API and its workers (migrating the database first, so a fresh one just works)."""
    import uvicorn

    from roadlink.api import create_app

    settings = _settings(host=host, port=port, workers=workers)
    if settings.auth == "disabled" and not is_loopback(settings.host):
        typer.echo(
            f"error: ROADLINK_AUTH=disabled turns API keys off, which is only for local "
            f"development: it is refused on {settings.host}, which other machines can reach. "
            "Listen on 127.0.0.1 (--host 127.0.0.1), or create keys with `roadlink keys create` "
            "and leave ROADLINK_AUTH unset.",
            err=True,
        )
        raise typer.Exit(code=2)
    configure_logging(settings)
    _migrate(settings)
    _say_how_to_get_a_key(settings)
    _exit_on_sigterm()
    # The event loop answers /healthz and every async route; request threads that parse, store
    # or draw hold the GIL in turns of this length, so a shorter turn keeps the loop prompt.
    sys.setswitchinterval(API_SWITCH_INTERVAL_SECONDS)
    pool = WorkerPool(settings, settings.workers)
    # From the first worker's start on, a signal must reach `pool.stop()`: a Ctrl-C that came
    # between the start and the `try` left this process waiting at exit for workers that do not
    # stop while it lives.
    try:
        pool.start()
        log.info("started %d worker process(es) on %s", settings.workers, _safe_url(settings))
        api = create_app(settings)
        # Everything loaded so far (the libraries, the app) lives as long as the process: frozen
        # out of the collector's sight, a full collection no longer walks it, which stalled
        # every request for 100-370 ms at a time (measured with benchmarks/soak.py).
        gc.collect()
        gc.freeze()
        uvicorn.run(api, **uvicorn_options(settings))
    finally:
        pool.stop()


def uvicorn_options(settings: Settings) -> dict[str, Any]:
    """How `serve` runs uvicorn."""
    from uvicorn.config import LOGGING_CONFIG

    return {
        "host": settings.host,
        "port": settings.port,
        "log_level": settings.log_level,
        # JSON: no configuration of uvicorn's own, so that its loggers, the access log among
        # them, reach the handler `configure_logging` set up and its JSON lines.
        "log_config": None if settings.log_format == "json" else LOGGING_CONFIG,
        "timeout_keep_alive": settings.keep_alive_seconds,
        "timeout_graceful_shutdown": graceful_shutdown_seconds(settings),
    }


def graceful_shutdown_seconds(settings: Settings) -> int:
    """How long a stopping API lets requests in flight finish: a `?wait=` request may take
    ROADLINK_MAX_WAIT_SECONDS, and draining must not cut it, but must not hang for ever on a
    request that never ends either (uvicorn's default)."""
    return math.ceil(settings.max_wait_seconds + GRACEFUL_SHUTDOWN_MARGIN_SECONDS)


@app.command("worker")
def worker_command(
    workers: Annotated[
        int | None,
        typer.Option(min=1, help="Worker processes to run [ROADLINK_WORKERS; default: cores]."),
    ] = None,
    check: Annotated[
        bool,
        typer.Option(
            "--check",
            help="Run no worker: exit 0 if a worker process on this host is alive (its "
            "heartbeat file in ROADLINK_WORKER_HEARTBEAT_DIR touched within "
            "ROADLINK_LEASE_SECONDS), else 1. For container health checks.",
        ),
    ] = False,
) -> None:
    """Run workers only, against ROADLINK_DATABASE_URL (to scale out beside `serve`)."""
    settings = _settings(workers=workers)
    if check:
        _check_workers(settings)
    workers = settings.workers
    if workers < 1:
        typer.echo(
            "error: `roadlink worker` needs at least one worker (ROADLINK_WORKERS)", err=True
        )
        raise typer.Exit(code=2)
    if workers == 1:
        from roadlink.queue.worker import run_worker_process

        run_worker_process(settings)
        return
    configure_logging(settings)
    _exit_on_sigterm()
    pool = WorkerPool(settings, workers)
    try:  # from the first worker's start on, as in `serve`
        pool.start()
        pool.join()
    except (KeyboardInterrupt, SystemExit):
        pass
    finally:
        pool.stop()


def _check_workers(settings: Settings) -> None:
    from roadlink.queue.liveness import live_workers

    alive = live_workers(settings.worker_heartbeat_dir, within_seconds=settings.lease_seconds)
    if not alive:
        typer.echo(
            f"no worker heartbeat within {settings.lease_seconds:g} s in "
            f"{settings.worker_heartbeat_dir}",
            err=True,
        )
        raise typer.Exit(code=1)
    typer.echo(f"{len(alive)} worker process(es) alive: {', '.join(alive)}")
    raise typer.Exit(code=0)


@app.command("migrate")
def migrate_command() -> None:
    """Bring the database schema to the newest migration (alembic upgrade head)."""
    settings = _settings()
    _migrate(settings)
    typer.echo(f"database at the newest schema: {_safe_url(settings)}", err=True)


@app.command("openapi")
def openapi_command(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="Where to write ('-' = stdout).")
    ] = Path("openapi/openapi.json"),
) -> None:
    """Write the OpenAPI document of the API (the committed contract is openapi/openapi.json)."""
    from roadlink.api.app import create_app, openapi_json
    from roadlink.settings import Settings

    text = openapi_json(create_app(Settings(database_url="sqlite://")))
    if str(output) == "-":
        typer.echo(text, nl=False)
        return
    output.parent.mkdir(parents=True, exist_ok=True)
    output.write_text(text, encoding="utf-8")
    typer.echo(f"wrote {output}", err=True)


def is_loopback(host: str) -> bool:
    """True when `host` is reachable from this machine only (127.0.0.0/8, ::1, localhost)."""
    import ipaddress

    if host.strip("[]").lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host.strip("[]")).is_loopback
    except ValueError:  # a host name other than localhost may resolve anywhere
        return False


def _say_how_to_get_a_key(settings: Settings) -> None:
    """On a database without an admin key, say how to create the first one."""
    from roadlink.db.apikeys import has_admin_key
    from roadlink.db.engine import engine_for, make_session_factory

    if settings.auth == "disabled":
        log.warning("ROADLINK_AUTH=disabled: every /v1 route is open (local development only)")
        return
    engine = engine_for(settings)
    try:
        with make_session_factory(engine)() as session:
            found = has_admin_key(session)
    finally:
        engine.dispose()
    if not found:
        typer.echo(
            "No API key exists yet, and every /v1 request needs one. Create the first (it is "
            "printed once) with:\n"
            "    roadlink keys create --scope admin\n"
            "and send it as `Authorization: Bearer <key>`.",
            err=True,
        )


def _safe_url(settings: Settings) -> str:
    from sqlalchemy import make_url

    return make_url(settings.database_url).render_as_string(hide_password=True)
