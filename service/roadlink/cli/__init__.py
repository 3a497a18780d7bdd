"""The roadlink command. Each module registers its own sub-commands on `app`."""

from __future__ import annotations

import gc

import typer

app = typer.Typer(
    name="roadlink",
    help="Group anonymous roadside detections into one row per vehicle.",
    no_args_is_help=True,
    add_completion=False,
)

# Sub-command modules register themselves on import.
from roadlink.cli import (  # noqa: E402,F401
    analysis,
    backup,
    config,
    follow,
    keys,
    locate,
    remote,
    reproduce,
    server,
    sumo,
)


def main() -> None:
    """The `roadlink` command: `app`, then the interpreter's end without its last garbage
    collections over every object still alive (numpy's, polars', scipy's modules, a
    command's result): after `gc.freeze` they are freed by reference counting alone, and the
    process ends in 0.06 s instead of 0.13 (a 10^6-detection `associate`). The standard
    streams are still flushed and `atexit` handlers (logging's) still run."""
    try:
        app()
    finally:
        gc.freeze()


__all__ = ["app", "main"]
