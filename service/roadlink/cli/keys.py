"""`roadlink keys create | list | revoke`: API keys, managed on the database directly (so the
first admin key needs no running server)."""

from __future__ import annotations

import uuid
from typing import Annotated

import typer

from roadlink.cli.root import app
from roadlink.cli.server import _migrate, _safe_url, _settings
from roadlink.db.enums import ApiKeyScope

keys_app = typer.Typer(
    help="Create, list and revoke API keys (the service needs one on every /v1 request).",
    no_args_is_help=True,
)
app.add_typer(keys_app, name="keys")


@keys_app.command("create")
def create_command(
    scope: Annotated[
        ApiKeyScope,
        typer.Option(
            help="ingest: post batches to the --deployment(s); read: read everything and run "
            "jobs; admin: everything, deployments and keys included."
        ),
    ],
    deployment: Annotated[
        list[uuid.UUID] | None,
        typer.Option(help="A deployment an ingest key may post to (repeat for several)."),
    ] = None,
    name: Annotated[
        str | None, typer.Option(help="What the key is for, e.g. the gateway's name.")
    ] = None,
) -> None:
    """Create a key and print it (only the key, on stdout). It is shown this once: only its
    hash is stored."""
    from roadlink.db import repository
    from roadlink.db.apikeys import create_api_key
    from roadlink.db.engine import engine_for, make_session_factory, transaction

    settings = _settings()
    _migrate(settings)  # a fresh database gets its schema, so this can be the very first step
    engine = engine_for(settings)
    try:
        with transaction(make_session_factory(engine)) as session:
            for deployment_id in deployment or ():
                if repository.get_deployment(session, deployment_id=deployment_id) is None:
                    raise ValueError(f"there is no deployment {deployment_id}")
            issued = create_api_key(
                session, scope=scope, deployment_ids=deployment or (), name=name
            )
            described = f"{scope.value} key {issued.row.prefix} (id {issued.row.id})"
    except ValueError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=2) from None
    finally:
        engine.dispose()
    typer.echo(
        f"created {described} in {_safe_url(settings)}; this is the only time it is shown:",
        err=True,
    )
    typer.echo(issued.key)


@keys_app.command("list")
def list_command(
    all_keys: Annotated[bool, typer.Option("--all", help="Include revoked keys.")] = False,
) -> None:
    """The keys: id, public prefix, scope, deployments, name, creation (never the secret)."""
    from roadlink.db.apikeys import list_api_keys
    from roadlink.db.engine import engine_for, make_session_factory

    settings = _settings()
    engine = engine_for(settings)
    try:
        with make_session_factory(engine)() as session:
            rows = list_api_keys(session, include_revoked=all_keys)
    finally:
        engine.dispose()
    if not rows:
        typer.echo("no API keys; create one with `roadlink keys create --scope admin`", err=True)
        return
    typer.echo("id\tprefix\tscope\tdeployments\tname\tcreated\trevoked")
    for row in rows:
        typer.echo(
            "\t".join(
                [
                    str(row.id),
                    row.prefix,
                    row.scope,
                    ",".join(row.deployment_ids or ()) or "-",
                    row.name or "-",
                    row.created_at.isoformat(timespec="seconds"),
                    row.revoked_at.isoformat(timespec="seconds") if row.revoked_at else "-",
                ]
            )
        )


@keys_app.command("revoke")
def revoke_command(
    key: Annotated[str, typer.Argument(help="The key's id or its public prefix.")],
) -> None:
    """Revoke a key: from now on every request with it is refused (401)."""
    from roadlink.db.apikeys import find_api_key, revoke_api_key
    from roadlink.db.engine import engine_for, make_session_factory, transaction

    settings = _settings()
    engine = engine_for(settings)
    try:
        with transaction(make_session_factory(engine)) as session:
            row = find_api_key(session, reference=key)
            if row is None:
                typer.echo(f"error: there is no API key {key}", err=True)
                raise typer.Exit(code=2)
            revoked = revoke_api_key(session, key_id=row.id)
            described = f"{row.scope} key {row.prefix} (id {row.id})"
    finally:
        engine.dispose()
    typer.echo(f"revoked {described}" if revoked else f"{described} was already revoked")
