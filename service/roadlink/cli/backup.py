"""`roadlink backup PATH`: a consistent copy of the database while the service runs (SQLite),
or how to make one (PostgreSQL: pg_dump)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from roadlink.cli.root import app


@app.command("backup")
def backup_command(
    path: Annotated[Path, typer.Argument(help="The new file to write (never overwritten).")],
) -> None:
    """Copy the SQLite database of ROADLINK_DATABASE_URL to PATH, consistently, while the
    service runs (VACUUM INTO); on PostgreSQL, print the pg_dump command that does it."""
    # Imported here, as every command's own modules: `roadlink associate` need not pay them.
    from roadlink.db.drivers import BackupAdvice, driver_for
    from roadlink.settings import Settings

    settings = Settings()
    try:
        driver_for(settings.database_url).backup(str(path))
    except BackupAdvice as advice:
        typer.echo(str(advice), err=True)
        raise typer.Exit(code=1) from None
    except FileExistsError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=1) from None
    typer.echo(f"copied the database to {path}", err=True)
