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
from service.cli import analysis, reproduce  # noqa: E402,F401

__all__ = ["app"]
from service.cli import server  # noqa: E402,F401

# isort: split
from service.cli import sumo  # noqa: E402,F401
