"""`roadlink config`: the configuration reference, generated from the settings themselves."""

from __future__ import annotations

from enum import StrEnum
from typing import Annotated

import typer

from roadlink.cli.root import app


class ConfigFormat(StrEnum):
    markdown = "markdown"
    env = "env"


@app.command("config")
def config_command(
    format: Annotated[
        ConfigFormat,
        typer.Option(
            "--format", help="markdown: the table of docs/configuration.md; env: .env.example."
        ),
    ] = ConfigFormat.markdown,
) -> None:
    """Print every ROADLINK_* setting with its default and meaning."""
    # Imported here: pydantic-settings costs every command's start 0.05 s.
    from roadlink.configuration import env_example, markdown_table

    typer.echo(markdown_table() if format is ConfigFormat.markdown else env_example(), nl=False)
