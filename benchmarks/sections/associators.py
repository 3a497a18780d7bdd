"""Seconds, peak memory and accuracy of every registered associator, from 10^3 to 10^6 detections.

Each (associator, size) runs in a child process of its own (`benchmarks.isolated`), so peak memory
is that child's alone. A size whose repeat exceeds the time limit marks the associator infeasible
beyond the previous size, and its larger sizes are skipped rather than waited for.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from benchmarks.datasets import SENSORS, cached_dataset, scaled_config, targets_for
from benchmarks.isolated import IsolatedRun, RunSpec, run_isolated
from benchmarks.report import Cell, Column, Sample, Section, Table
from roadlink.association.associators import ASSOCIATORS

NAME = "associators"


@dataclass(frozen=True)
class ScalingPlan:
    """Sizes (detections), the per-repeat time limit, and how many repeats to take."""

    sizes: tuple[int, ...]
    time_limit: float
    repeats: int
    min_repeats: int = 3
    budget_seconds: float = 30.0


FULL = ScalingPlan(
    sizes=(1_000, 3_000, 10_000, 30_000, 100_000, 300_000, 1_000_000),
    time_limit=60.0,
    repeats=5,
)
QUICK = ScalingPlan(sizes=(1_000, 10_000), time_limit=5.0, repeats=3, budget_seconds=5.0)


def run(quick: bool) -> Section:
    """Every associator in the registry on growing simulated data (see module docstring)."""
    return measure_scaling(list(ASSOCIATORS), QUICK if quick else FULL)


def measure_scaling(methods: Sequence[str], plan: ScalingPlan, name: str = NAME) -> Section:
    """Run each method on each size in `plan`; a method stops at its first size over the limit."""
    section = Section(
        name=name,
        description=(
            f"Seconds to group, peak memory (RSS of a child process running one method on one "
            f"size) and accuracy, on the paper's 'large' preset stretched to {SENSORS} sensors "
            f"at the same traffic density. Seconds are the median [min, max] of "
            f"{_repeats(plan)}; a repeat over {plan.time_limit:g} s stops the method. Memory above "
            "baseline is the peak minus the RSS after imports and loading the data."
        ),
        settings={
            "sizes": list(plan.sizes),
            "sensors": SENSORS,
            "time_limit_seconds": plan.time_limit,
            "repeats": plan.repeats,
            "min_repeats": plan.min_repeats,
            "budget_seconds": plan.budget_seconds,
        },
    )
    table = Table(
        "Scaling",
        [
            Column("method"),
            Column("detections", "count"),
            Column("targets", "count"),
            Column("seconds", "seconds"),
            Column("peak memory", "mib"),
            Column("memory above baseline", "mib"),
            Column("accuracy", "share"),
            Column("outcome"),
        ],
    )
    for method in methods:
        feasible_up_to: int | None = None
        for size in plan.sizes:
            n_targets = targets_for(size)
            dataset = cached_dataset(scaled_config(n_targets))
            spec = RunSpec(
                method=method,
                dataset=str(dataset),
                repeats=plan.repeats,
                min_repeats=plan.min_repeats,
                budget_seconds=plan.budget_seconds,
            )
            outcome = run_isolated(spec, plan.time_limit)
            table.add(*_row(method, n_targets, outcome))
            if outcome.outcome != "ok":
                beyond = "any size" if feasible_up_to is None else f"{feasible_up_to:,}"
                why = (
                    f"a repeat exceeded {plan.time_limit:g} s at {n_targets * SENSORS:,}"
                    if outcome.outcome == "timeout"
                    else f"it failed at {n_targets * SENSORS:,}: {outcome.error}"
                )
                table.notes.append(f"- {method}: infeasible beyond {beyond} detections ({why}).")
                break
            feasible_up_to = n_targets * SENSORS
    section.tables.append(table)
    return section


def _repeats(plan: ScalingPlan) -> str:
    if plan.min_repeats == plan.repeats:
        return f"{plan.repeats} repeats"
    return (
        f"{plan.repeats} repeats ({plan.min_repeats} once they have taken "
        f"{plan.budget_seconds:g} s)"
    )


def _row(method: str, n_targets: int, run: IsolatedRun) -> list[Cell]:
    seconds = Sample.of(run.seconds) if run.seconds else None
    above = (
        None
        if run.peak_rss_mib is None or run.baseline_rss_mib is None
        else run.peak_rss_mib - run.baseline_rss_mib
    )
    outcome = {"ok": "ok", "timeout": "over time limit", "error": f"error: {run.error}"}
    return [
        method,
        n_targets * SENSORS,
        n_targets,
        seconds,
        run.peak_rss_mib,
        above,
        run.accuracy,
        outcome[run.outcome],
    ]
