"""Commands against a running server, for analysts: submit, result, jobs.

They talk HTTP only (`roadlink.cli.client`), so they work from any machine that reaches the API,
with the server at --url / ROADLINK_URL and the key at --key / ROADLINK_KEY. An error answer is
printed as one line (`error: 404 Not Found: there is no deployment ...`) and exits 1.
"""

from __future__ import annotations

import json
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Annotated, Any

import typer

from roadlink.association.associators import ASSOCIATORS, DEFAULT_ASSOCIATOR
from roadlink.cli.analysis import ParamOption, print_summary
from roadlink.cli.client import DEFAULT_URL, Remote, RemoteError
from roadlink.cli.root import app
from roadlink.db.enums import JobState

# How often `submit --wait` asks for the job's progress: well inside the default rate limit
# (20 requests per second per key), and often enough for a bar that moves.
POLL_SECONDS = 0.5
FINISHED = {JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED}
# The server's largest page (GET /v1/jobs?limit=).
MAX_PAGE_SIZE = 1000

UrlOption = Annotated[
    str, typer.Option("--url", envvar="ROADLINK_URL", help="The server's address.")
]
KeyOption = Annotated[
    str | None,
    typer.Option(
        "--key",
        envvar="ROADLINK_KEY",
        help="API key, sent as `Authorization: Bearer`.",
        show_default=False,
    ),
]


@contextmanager
def remote(url: str, key: str | None) -> Iterator[Remote]:
    """The server, with any failure to talk to it ending the command: one line, exit code 1."""
    try:
        with Remote(url, key) as server:
            yield server
    except RemoteError as exc:
        typer.echo(f"error: {exc}", err=True)
        raise typer.Exit(code=1) from None


@app.command("submit")
def submit_command(
    file: Annotated[
        Path, typer.Argument(exists=True, dir_okay=False, help="The detection CSV to post.")
    ],
    deployment: Annotated[uuid.UUID, typer.Option(help="The deployment the batch belongs to.")],
    associator: Annotated[
        str, typer.Option(help=f"One of: {', '.join(ASSOCIATORS)}.")
    ] = DEFAULT_ASSOCIATOR,
    param: ParamOption = None,
    wait: Annotated[
        bool, typer.Option("--wait", help="Show the job's progress, then its result's summary.")
    ] = False,
    url: UrlOption = DEFAULT_URL,
    key: KeyOption = None,
) -> None:
    """Post a CSV batch with its association job; print the batch and job ids (`batch <id>`,
    `job <id>`). Ctrl-C during --wait stops waiting, not the job."""
    with remote(url, key) as server:
        batch = server.json(
            "POST",
            f"/v1/deployments/{deployment}/batches",
            content=file.read_bytes(),
            headers={"content-type": "text/csv"},
            params={"associator": associator, "param": param or []},
        )
        job_id = batch["job"]["id"]
        typer.echo(f"batch {batch['id']}")
        typer.echo(f"job {job_id}")
        if not wait:
            return
        job = follow_job(server, job_id)
        if job["state"] != JobState.SUCCEEDED:
            raise RemoteError(f"job {job_id} {job['state']}: {job['error'] or 'no error given'}")
        print_summary(server.json("GET", f"/v1/jobs/{job_id}/result"))


def follow_job(server: Remote, job_id: str) -> dict[str, Any]:
    """Poll the job until it finishes, drawing its progress on stderr; the finished job."""
    from rich.console import Console
    from rich.progress import (
        BarColumn,
        Progress,
        TaskProgressColumn,
        TextColumn,
        TimeElapsedColumn,
    )

    columns = (
        TextColumn("job {task.fields[state]:<9}"),
        BarColumn(),
        TaskProgressColumn(),
        TimeElapsedColumn(),
    )
    with Progress(*columns, console=Console(stderr=True)) as bar:
        task = bar.add_task("job", total=1.0, state=JobState.QUEUED.value)
        while True:
            job: dict[str, Any] = server.json("GET", f"/v1/jobs/{job_id}")
            bar.update(task, completed=job["progress"], state=job["state"])
            if job["state"] in FINISHED:
                return job
            time.sleep(POLL_SECONDS)


@app.command("result")
def result_command(
    job: Annotated[uuid.UUID, typer.Argument(help="The job's id.")],
    as_json: Annotated[bool, typer.Option("--json", help="The result document.")] = False,
    as_csv: Annotated[bool, typer.Option("--csv", help="The target x sensor matrix X''.")] = False,
    output: Annotated[
        Path | None, typer.Option("-o", "--output", help="Write it here (JSON unless --csv).")
    ] = None,
    wait: Annotated[
        float, typer.Option(min=0, help="Seconds to wait for an unfinished job (server-capped).")
    ] = 0.0,
    url: UrlOption = DEFAULT_URL,
    key: KeyOption = None,
) -> None:
    """A finished job's result: its summary, as `roadlink associate` prints it, or with --json
    or --csv the document itself."""
    if as_json and as_csv:
        typer.echo("error: --json and --csv exclude each other", err=True)
        raise typer.Exit(code=2)
    with remote(url, key) as server:
        answer = server.request(
            "GET",
            f"/v1/jobs/{job}/result",
            params={"format": "csv" if as_csv else "json", "wait": wait},
        )
    if as_csv:
        text = answer.text
    elif as_json or output is not None:
        text = json.dumps(answer.json(), indent=2) + "\n"
    else:
        print_summary(answer.json())
        return
    if output is None:
        sys.stdout.write(text)
        return
    output.write_text(text, encoding="utf-8")
    typer.echo(f"wrote {output}", err=True)


@app.command("jobs")
def jobs_command(
    state: Annotated[JobState | None, typer.Option(help="Only jobs in this state.")] = None,
    deployment: Annotated[
        uuid.UUID | None, typer.Option(help="Only this deployment's jobs.")
    ] = None,
    limit: Annotated[int, typer.Option(min=1, help="Most jobs to list.")] = 20,
    page_size: Annotated[
        int, typer.Option(min=1, max=MAX_PAGE_SIZE, help="Jobs asked for per request.")
    ] = MAX_PAGE_SIZE,
    url: UrlOption = DEFAULT_URL,
    key: KeyOption = None,
) -> None:
    """Jobs, newest first: id, state, progress, associator, deployment, created. The server
    sends them a page at a time; this follows each page's `next` link until `--limit`."""
    query: dict[str, str | int] = {"limit": min(limit, page_size)}
    if state is not None:
        query["state"] = state.value
    if deployment is not None:
        query["deployment_id"] = str(deployment)
    typer.echo("id\tstate\tprogress\tassociator\tdeployment\tcreated")
    shown = 0
    with remote(url, key) as server:
        page = server.json("GET", "/v1/jobs", params=query)
        while True:
            for job in page["items"][: limit - shown]:
                fields = (job["state"], f"{job['progress']:.2f}", job["associator"])
                typer.echo("\t".join((job["id"], *fields, job["deployment_id"], job["created_at"])))
                shown += 1
            if shown >= limit or page["next"] is None:
                return
            page = server.json("GET", page["next"])
