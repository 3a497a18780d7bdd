"""`roadlink simulate-sumo`: realistic traffic from Eclipse SUMO (the optional extra `sumo`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from roadlink.cli.analysis import fail, write_simulated
from roadlink.cli.root import app
from roadlink.simulation.sumo import (
    SUMO_SCENARIOS,
    SumoNotInstalledError,
    SumoRunError,
    run_sumo,
    sumo_scenario,
)


@app.command("simulate-sumo")
def simulate_sumo_command(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="CSV file to write ('-' = stdout).")
    ],
    scenario: Annotated[
        str, typer.Option(help=f"One of: {', '.join(SUMO_SCENARIOS)}.")
    ] = "sumo-freeflow",
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same data).")] = 0,
    duration: Annotated[
        float | None, typer.Option(help="Seconds of detections to keep (after the warm-up).")
    ] = None,
    demand: Annotated[float | None, typer.Option(help="Vehicles per hour.")] = None,
    workdir: Annotated[
        Path | None,
        typer.Option(help="Keep SUMO's network, route, detector and output files here."),
    ] = None,
    features: Annotated[
        bool,
        typer.Option(
            help="Detectors also report lane, vehicle length and class (lane, length and "
            "vehicle_class columns); lengths then spread within each vehicle class."
        ),
    ] = False,
    length_noise: Annotated[
        float | None,
        typer.Option(
            help="Length measurement error with --features (std, share of length; loops: "
            "0.05-0.10). Default: the scenario's (exact for the named scenarios)."
        ),
    ] = None,
    unlabelled: Annotated[bool, typer.Option(help="Leave the target column empty.")] = False,
) -> None:
    """Simulate road traffic (motorways, queues, traffic lights) with Eclipse SUMO and write
    what its loop detectors saw as CSV.

    Needs SUMO: pip install 'roadlink\\[sumo]'. The target column holds SUMO's vehicle ids.
    """
    overrides: dict[str, object] = {}
    if duration is not None:
        overrides["duration"] = duration
    if demand is not None:
        overrides["demand"] = demand
    if features:
        overrides["features"] = True
    if length_noise is not None:
        if not features:
            raise fail("--length-noise needs --features: without it no length is reported")
        base = SUMO_SCENARIOS.get(scenario)
        faults = base.faults.model_dump() if base is not None else {}
        overrides["faults"] = {**faults, "length_noise": length_noise}
    try:
        config = sumo_scenario(scenario, **overrides)
    except ValueError as exc:
        raise fail(str(exc)) from None
    try:
        detections = run_sumo(config, seed=seed, workdir=workdir)
    except (SumoNotInstalledError, SumoRunError) as exc:
        raise fail(str(exc)) from None
    write_simulated(detections, output, unlabelled=unlabelled)
