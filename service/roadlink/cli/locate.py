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
from roadlink.association.detections import Detections
from roadlink.association.localisation import (
    SampledTrajectory,
    leg_stats,
    positions_at,
    published_trajectory,
    sample_trajectory,
    target_index,
    target_trajectories,
)
from roadlink.association.result import AssociationResult
from roadlink.cli.analysis import AssociatorOption, ParamOption, associate_file, fail
from roadlink.cli.root import app


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
    vehicles = _vehicles(result)
    described = tuple(
        name for name in ("length", "vehicle_class") if name in result.detections.features
    )

    if at is not None:
        rows = positions_at(result, at)
        if not rows and not as_json:
            typer.echo(f"no target is on the road at t={at:g}", err=True)
        _emit(_described(rows, vehicles), as_json, ("target", "position", "velocity", *described))
        return
    try:
        if segments:
            trajectories = target_trajectories(result)
            if target is not None:
                trajectories = [trajectories[target_index(target, len(trajectories))]]
            _emit(
                _described(leg_stats(trajectories), vehicles),
                as_json,
                (
                    "target",
                    "from_sensor",
                    "to_sensor",
                    "travel_time",
                    "distance",
                    "mean_speed",
                    *described,
                ),
            )
            return
        assert target is not None
        trajectory = sample_trajectory(result, target, step)
    except (KeyError, ValueError) as exc:
        raise fail(exc.args[0] if exc.args else str(exc)) from None
    if as_json:
        printed = _trajectory_dict(trajectory, vehicles[trajectory.target], result.detections)
        sys.stdout.write(json.dumps(printed, indent=2) + "\n")
        return
    if not trajectory.monotone:
        typer.echo(
            f"warning: {trajectory.target} goes backwards along the road between passes: "
            "its detections are probably grouped wrongly",
            err=True,
        )
    _emit(_described(trajectory.samples, {}), False, ("time", "position", "velocity"))


def _vehicles(result: AssociationResult) -> dict[str, dict[str, Any]]:
    """Each target's length and class by its name, for the features the input reports (see
    `AssociationResult.target_features`): empty without features, so the output is as before."""
    features = result.detections.features
    return {
        f"T{k + 1}": result.target_features(members, features)
        for k, members in enumerate(result.target_members())
    }


def _described(rows: Sequence[Any], vehicles: dict[str, dict[str, Any]]) -> list[dict[str, Any]]:
    """Dataclass rows as dicts, each about a target followed by that target's description."""
    return [{**dataclasses.asdict(r), **vehicles.get(getattr(r, "target", ""), {})} for r in rows]


def _trajectory_dict(
    trajectory: SampledTrajectory, vehicle: dict[str, Any], detections: Detections
) -> dict[str, Any]:
    """The trajectory as JSON: the target's description after its name, and on each pass the
    features its detection reported (the earliest, when duplicates were merged into it)."""
    printed = published_trajectory(trajectory)
    features = {name: detections.feature_values(name) for name in detections.features}
    if features:
        index = {i: k for k, i in enumerate(detections.detection_id.tolist())}
        for sensor_pass in printed["passes"]:
            first = index[sensor_pass["detection_ids"][0]]
            sensor_pass.update({name: values[first] for name, values in features.items()})
    target = {"target": printed.pop("target")}
    return {**target, **vehicle, **printed}


def _emit(rows: list[dict[str, Any]], as_json: bool, columns: tuple[str, ...]) -> None:
    """Rows as a JSON array, or as an aligned table of the chosen columns."""
    if as_json:
        sys.stdout.write(json.dumps(rows, indent=2) + "\n")
        return
    cells = [[_cell(r[c]) for c in columns] for r in rows]
    widths = [max([len(c), *(len(row[i]) for row in cells)]) for i, c in enumerate(columns)]
    typer.echo("  ".join(c.rjust(w) for c, w in zip(columns, widths, strict=True)))
    for row in cells:
        typer.echo("  ".join(v.rjust(w) for v, w in zip(row, widths, strict=True)))


def _cell(value: object) -> str:
    if value is None:
        return "-"
    return f"{value:.3f}" if isinstance(value, float) else str(value)
