"""roadlink beside its peer: Stone Soup's GNN tracker, on the same simulated data.

Stone Soup (the `bench` extra) is what a tracking engineer would reach for: a global-nearest-
neighbour tracker with a constant-velocity model. `benchmarks.stonesoup_gnn` explains how it is
set up. It runs beside roadlink's default associator and the paper's K-means++ on the paper's
presets and on `congested`, then on growing data until it becomes slow.
"""

from __future__ import annotations

import time

from benchmarks.datasets import SENSORS
from benchmarks.methods import STONESOUP_GNN, grouping_method, stonesoup_available
from benchmarks.report import Column, Sample, Section, Table
from benchmarks.sections.associators import ScalingPlan, measure_scaling
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.scores import score_grouping
from roadlink.simulation import preset, simulate

NAME = "peer"
PRESETS = ("large", "medium", "small", "congested")
FULL_SEEDS = 20
QUICK_SEEDS = 2
FULL_SCALING = ScalingPlan(sizes=(1_000, 3_000, 10_000, 30_000), time_limit=60.0, repeats=3)
QUICK_SCALING = ScalingPlan(sizes=(1_000,), time_limit=10.0, repeats=3, budget_seconds=3.0)


def compared_methods() -> list[str]:
    """Stone Soup, roadlink's default associator and K-means++ (once, if that is the default)."""
    return list(dict.fromkeys([STONESOUP_GNN, DEFAULT_ASSOCIATOR, "kmeans++"]))


def run(quick: bool) -> Section:
    """Accuracy and seconds per data set on each preset, then scaling (see module docstring)."""
    seeds = QUICK_SEEDS if quick else FULL_SEEDS
    if not stonesoup_available():
        return Section(
            NAME,
            "Stone Soup is not installed (pip install -e '.[bench]'); the peer was not run.",
            settings={"stonesoup": None},
        )
    from stonesoup import __version__ as stonesoup_version

    from benchmarks.stonesoup_gnn import TrackerSettings

    methods = compared_methods()
    section = Section(
        NAME,
        f"Stone Soup {stonesoup_version} GNN tracker (`GNNWith2DAssignment`, constant-velocity "
        f"model in (passing time, pace) with road position as its clock) beside "
        f"{_compared_registry(methods)}. Accuracy is the "
        f"paper's, over {seeds} seeds per preset (mean [min, max]); seconds per data set are "
        "the median [min, max] over the seeds, in one process, including building Stone Soup's "
        "detection objects.",
        settings={
            "stonesoup": stonesoup_version,
            "tracker": TrackerSettings().__dict__,
            "seeds": seeds,
            "methods": methods,
        },
    )
    table = Table(
        "Presets",
        [
            Column("preset"),
            Column("detections", "count"),
            *(Column(f"{m} accuracy", "share", statistic="mean") for m in methods),
            *(Column(f"{m} seconds", "seconds") for m in methods),
        ],
    )
    for name in PRESETS:
        datasets = [simulate(preset(name), seed=seed).detections for seed in range(seeds)]
        accuracy: dict[str, list[float]] = {m: [] for m in methods}
        seconds: dict[str, list[float]] = {m: [] for m in methods}
        for method in methods:
            group = grouping_method(method)
            for detections in datasets:
                start = time.perf_counter()
                groups = group(detections)
                seconds[method].append(time.perf_counter() - start)
                metrics = score_grouping(groups, detections.target)
                assert metrics is not None  # simulated detections are labelled
                accuracy[method].append(metrics.accuracy)
        table.add(
            name,
            len(datasets[0]),
            *(Sample.of(accuracy[m]) for m in methods),
            *(Sample.of(seconds[m]) for m in methods),
        )
    section.tables.append(table)

    scaling = measure_scaling(methods, QUICK_SCALING if quick else FULL_SCALING, name=NAME)
    scaling.tables[0].title = f"Scaling ({SENSORS} sensors, isolated processes)"
    section.tables += scaling.tables
    section.settings["scaling"] = scaling.settings
    return section


def _compared_registry(methods: list[str]) -> str:
    others = [m for m in methods if m != STONESOUP_GNN]
    return ", ".join(
        f"'{m}'" + (" (roadlink's default)" if m == DEFAULT_ASSOCIATOR else "") for m in others
    )
