"""`roadlink locate`: where the targets of a detection CSV are, once associated."""

from __future__ import annotations

import dataclasses
import json
import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer

from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.localisation import (
    positions_at,
    segment_stats,
    target_index,
    target_tracks,
    target_trajectory,
)
from roadlink.cli import app
from roadlink.cli.analysis import AssociatorOption, ParamOption, associate_file, fail


@app.command("locate")
def locate_command(
    file: Annotated[Path, typer.Argument(help="Detection CSV ('-' = stdin).")],
    at: Annotated[
        float | None, typer.Option("--at", help="Every target on the road at this time.")
    ] = None,
    target: Annotated[
        str | None,
        typer.Option("--target", help="One target's trajectory (T1 passes the reference first)."),
    ] = None,
    step: Annotated[
        float | None,
        typer.Option("--step", help="Sampling step of --target (default: 100 equal intervals)."),
    ] = None,
    segments: Annotated[
        bool,
        typer.Option("--segments", help="Travel time and mean speed between consecutive sensors."),
    ] = False,
    associator: AssociatorOption = DEFAULT_ASSOCIATOR,
    param: ParamOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print JSON instead of a table.")] = False,
) -> None:
    """Associate the detections, then localise the targets by cubic Hermite interpolation.

    Choose one of --at T (positions at a time), --target T3 [--step S] (a sampled trajectory,
    its passes and segments) and --segments (travel times of every target, or of --target).
    """
    chosen = sum([at is not None, target is not None and not segments, segments])
    if chosen != 1:
        raise fail("choose one of --at, --target and --segments")
    if at is not None and not math.isfinite(at):
        raise fail(f"--at must be a finite time, got {at}")
    if step is not None and target is None:
        raise fail("--step samples a trajectory: give --target too")
    result = associate_file(file, associator, param or [])

    if at is not None:
        rows = positions_at(result, at)
        if not rows and not as_json:
            typer.echo(f"no target is on the road at t={at:g}", err=True)
        _emit(rows, as_json, ("target", "position", "velocity"))
        return
    try:
        if segments:
            tracks = target_tracks(result)
            if target is not None:
                tracks = [tracks[target_index(target, len(tracks))]]
            _emit(
                segment_stats(tracks),
                as_json,
                ("target", "from_sensor", "to_sensor", "travel_time", "distance", "mean_speed"),
            )
            return
        assert target is not None
        trajectory = target_trajectory(result, target, step)
    except (KeyError, ValueError) as exc:
        raise fail(exc.args[0] if exc.args else str(exc)) from None
    if as_json:
        sys.stdout.write(json.dumps(dataclasses.asdict(trajectory), indent=2) + "\n")
        return
    if not trajectory.monotone:
        typer.echo(
            f"warning: {trajectory.target} goes backwards along the road between passes: "
            "its detections are probably grouped wrongly",
            err=True,
        )
    _emit(trajectory.samples, False, ("time", "position", "velocity"))


def _emit(rows: Sequence[Any], as_json: bool, columns: tuple[str, ...]) -> None:
    """Dataclass rows as a JSON array, or as an aligned table of the chosen columns."""
    if as_json:
        sys.stdout.write(json.dumps([dataclasses.asdict(r) for r in rows], indent=2) + "\n")
        return
    cells = [[_cell(getattr(r, c)) for c in columns] for r in rows]
    widths = [max([len(c), *(len(row[i]) for row in cells)]) for i, c in enumerate(columns)]
    typer.echo("  ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True)))
    for row in cells:
        typer.echo("  ".join(v.rjust(w) for v, w in zip(row, widths, strict=True)))


def _cell(value: object) -> str:
    return f"{value:.3f}" if isinstance(value, float) else str(value)
