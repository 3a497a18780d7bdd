"""`roadlink follow`: print a deployment's vehicles as its live association publishes them.

It reads the feed page by page with a long poll (`GET .../vehicles?after=&wait=`), so it
needs no polling loop of its own and resumes exactly where it stopped when given `--after`
(the cursor it printed last, on stderr, when interrupted)."""

from __future__ import annotations

import csv
import json
import sys
import uuid
from typing import Annotated, Any

import typer

from roadlink.association.csvio import spreadsheet_safe
from roadlink.cli.client import DEFAULT_URL
from roadlink.cli.remote import KeyOption, UrlOption, remote
from roadlink.cli.root import app

# The longest a single long poll waits; the server caps it at ROADLINK_MAX_WAIT_SECONDS.
POLL_WAIT_SECONDS = 30.0
CSV_COLUMNS = (
    "vehicle_id",
    "confidence",
    "detection_id",
    "batch_id",
    "sensor_id",
    "position",
    "velocity",
    "timestamp",
)


@app.command("follow")
def follow_command(
    deployment: Annotated[uuid.UUID, typer.Option(help="The deployment to follow.")],
    as_csv: Annotated[
        bool, typer.Option("--csv", help="One CSV row per detection instead of JSON lines.")
    ] = False,
    after: Annotated[
        str, typer.Option(help="Start after this cursor (default: the first vehicle).")
    ] = "",
    until_idle: Annotated[
        bool,
        typer.Option("--until-idle", help="Stop once every vehicle published so far is printed."),
    ] = False,
    url: UrlOption = DEFAULT_URL,
    key: KeyOption = None,
) -> None:
    """Print the deployment's vehicles as they are published: one JSON object per line (the
    feed's vehicle), or with --csv one row per detection. Ctrl-C stops; the last cursor is
    printed on stderr, for --after."""
    writer = csv.writer(sys.stdout, lineterminator="\n") if as_csv else None
    if writer is not None:
        writer.writerow(CSV_COLUMNS)
    cursor = after
    try:
        with remote(url, key) as server:
            while True:
                page = server.json(
                    "GET",
                    f"/v1/deployments/{deployment}/vehicles",
                    params={
                        "after": cursor,
                        "limit": 1000,
                        "wait": 0 if until_idle else POLL_WAIT_SECONDS,
                    },
                )
                for vehicle in page["items"]:
                    _print(vehicle, writer)
                sys.stdout.flush()
                cursor = page["next_cursor"]
                if until_idle and not page["items"]:
                    return
    except KeyboardInterrupt:
        typer.echo(f"stopped after cursor {cursor or '(none)'}", err=True)


def _print(vehicle: dict[str, Any], writer: Any) -> None:
    if writer is None:
        sys.stdout.write(json.dumps(vehicle, separators=(",", ":")) + "\n")
        return
    for item in vehicle["detections"]:
        row = [vehicle["vehicle_id"], vehicle["confidence"], *(item[c] for c in CSV_COLUMNS[2:])]
        writer.writerow(["" if v is None else spreadsheet_safe(str(v)) for v in row])
