"""The roadlink command. Each module registers its own sub-commands on `app`."""

from __future__ import annotations

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

__all__ = ["app"]
