"""The `roadlink` command's root, on which each command module registers its sub-commands."""

from __future__ import annotations

import typer

app = typer.Typer(
    name="roadlink",
    help="Group anonymous roadside detections into one row per vehicle.",
    no_args_is_help=True,
    add_completion=False,
)


@app.callback()
def root() -> None:
    """Keeps `roadlink` a group of commands however few are registered: `main` registers only
    the module of the command it runs, and a group of one command would run it unnamed."""
