"""Accuracy of every registered associator on realistic traffic simulated by Eclipse SUMO.

Each SUMO scenario (service/roadlink/simulation/sumo/scenarios.py) is simulated with seeds
0 .. N-1 and every associator in the registry groups it with its default parameters; supervised
ones (the SVMs) are given the labels and scored out of fold, as the paper did. The naive
references of benchmarks/references.py (`fifo`, `chain`) can be added with `--associators`.
The table gives the mean, the standard deviation and the worst seed's accuracy; a run longer
than `--timeout` seconds is stopped and counted as timed out (metrics null in the JSON).
Writes benchmarks/results/sumo_accuracy.json.

    pip install 'roadlink[sumo]'
    python benchmarks/sumo_accuracy.py --seeds 5 --export /work/sumo-data
    python benchmarks/sumo_accuracy.py --data /work/sumo-data    # the CSVs, without SUMO
    python benchmarks/sumo_accuracy.py --associators assignment --scenarios sumo-dense

`--export DIR` also writes each simulated case as DIR/<scenario>-seed<N>.csv; `--data DIR` reads
those files instead of running SUMO, so the table can be remade where SUMO is not installed.

`--validation` runs, instead of the named scenarios, the variants in VALIDATION: other roads,
demands and faults, kept apart from the scenarios that the associator's defaults were first
measured on, to check that a change of the defaults holds on traffic it was not tuned on.
`--speed-noise` runs the variants in SPEED_NOISE: free-flowing and dense traffic seen by loops
that measure speed with an error of 3, 6 or 10 %, and no other fault.

`--features` runs the same scenarios with detectors that also report lane, vehicle length
(measured with a `--length-noise` error, 7 % by default) and class, each vehicle class's lengths
spread over its range (the scenario's `features` option), and scores every associator twice on
each case: with the features, and on the same detections without them (column `... -f`).
`--lanes-alone` adds a third score, on the same detections reporting their lane alone (column
`... -l`: single loops know their lane and measure no length). Export feature cases to a
directory of their own: their names are the scenarios'.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import time
from pathlib import Path

import numpy as np

from roadlink.association import associate
from roadlink.association.associators import ASSOCIATORS
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.detections import CLUTTER, Detections
from roadlink.association.scores import score_grouping
from roadlink.simulation.sumo import (
    SUMO_SCENARIOS,
    Bottleneck,
    DetectorFaults,
    SumoScenario,
    mix,
    run_sumo,
    sumo_scenario,
)

try:
    from benchmarks.references import REFERENCES
except ModuleNotFoundError:  # run as a script (python benchmarks/sumo_accuracy.py): its folder
    from references import REFERENCES  # type: ignore[no-redef]  # is on the path

RESULTS = Path(__file__).parent / "results" / "sumo_accuracy.json"


def _spaced(first: float, gaps: list[int]) -> list[float]:
    return [first + float(g) for g in np.cumsum([0, *gaps])]


VALIDATION: dict[str, SumoScenario] = {
    "val-urban": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes at 50 km/h, 1200 veh/h, 11 sensors every 100 m.",
        lanes=2,
        speed_limit=13.89,
        demand=1200.0,
        road_length=1500.0,
        sensor_positions=[100.0 + 100.0 * i for i in range(11)],
    ),
    "val-medium": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h, 12 sensors every 150 m.",
        demand=3000.0,
        sensor_positions=[200.0 + 150.0 * i for i in range(12)],
    ),
    "val-slowzone": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 2500 veh/h, 50 km/h limit at 1.2-1.8 km (no lane drop).",
        demand=2500.0,
        bottleneck=Bottleneck(start=1200.0, end=1800.0, speed_limit=13.9),
        warmup=300.0,
    ),
    "val-wide": sumo_scenario(
        "sumo-freeflow",
        description="4 lanes, 6000 veh/h, 11 sensors every 400 m on a 5 km road.",
        lanes=4,
        demand=6000.0,
        road_length=5000.0,
        sensor_positions=[300.0 + 400.0 * i for i in range(11)],
        duration=120.0,
        warmup=300.0,
    ),
    "val-trucks-faulty": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 2000 veh/h, half trucks; 3% missed, 2% false alarms, 1% speed error.",
        demand=2000.0,
        vehicles=mix(car=0.5, truck=0.5),
        faults=DetectorFaults(miss_probability=0.03, false_alarm_rate=0.02, velocity_noise=0.01),
    ),
    "val-queue-irregular": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h, sensors 60-600 m apart, a lane drop to 1 lane at "
        "2.9-3.4 km, beyond the last sensor: a queue over irregularly spaced sensors.",
        demand=3000.0,
        sensor_positions=_spaced(150.0, [60, 600, 250, 90, 400, 180, 520, 120, 300]),
        bottleneck=Bottleneck(start=2900.0, end=3400.0, lanes=1, speed_limit=11.0),
        road_length=3800.0,
        warmup=900.0,
        duration=300.0,
    ),
    "val-congestion": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 1800 veh/h through a slow zone limited to 8 m/s at 0.8-2.0 km.",
        lanes=2,
        demand=1800.0,
        bottleneck=Bottleneck(start=800.0, end=2000.0, speed_limit=8.0),
        warmup=400.0,
        duration=300.0,
    ),
    "val-lanedrop": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes dropping to 2 at 2.0-2.6 km, 3600 veh/h.",
        demand=3600.0,
        bottleneck=Bottleneck(start=2000.0, end=2600.0, lanes=2),
        warmup=400.0,
    ),
    # Queues and noisy speeds kept apart while the lane anchors' chains learned their smoothness
    # and margins (2026-11-26): never tuned on.
    "val-stopgo3": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3600 veh/h into a 1.2 km zone limited to 5 m/s (1.3-2.5 km).",
        demand=3600.0,
        bottleneck=Bottleneck(start=1300.0, end=2500.0, speed_limit=5.0),
        warmup=600.0,
        duration=300.0,
    ),
    "val-lanedrop2": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2000 veh/h, dropping to 1 lane at 15 m/s at 2.3-2.8 km, sensors "
        "150-700 m apart.",
        lanes=2,
        demand=2000.0,
        bottleneck=Bottleneck(start=2300.0, end=2800.0, lanes=1, speed_limit=15.0),
        sensor_positions=[
            150.0,
            350.0,
            700.0,
            900.0,
            1250.0,
            1400.0,
            1700.0,
            2000.0,
            2200.0,
            2900.0,
        ],
        road_length=3200.0,
        warmup=700.0,
        duration=300.0,
    ),
    "val-creep": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 3000 veh/h crawling through a zone limited to 2.5 m/s "
        "(1.5-2.3 km), 12 sensors every 200 m, a 240 s window.",
        demand=3000.0,
        bottleneck=Bottleneck(start=1500.0, end=2300.0, speed_limit=2.5),
        sensor_positions=[200.0 + 200.0 * i for i in range(12)],
        warmup=500.0,
        duration=240.0,
    ),
    "val-dense-noise8": sumo_scenario(
        "sumo-dense",
        description="sumo-dense with speeds measured with an 8 % error.",
        faults=DetectorFaults(velocity_noise=0.08),
    ),
    "val-crawl2": sumo_scenario(
        "sumo-freeflow",
        description="2 lanes, 2200 veh/h into a 1.2 km zone limited to 3 m/s, 15 sensors every "
        "150 m.",
        lanes=2,
        demand=2200.0,
        bottleneck=Bottleneck(start=1200.0, end=2400.0, speed_limit=3.0),
        sensor_positions=[150.0 + 150.0 * i for i in range(15)],
        road_length=2800.0,
        warmup=600.0,
        duration=300.0,
    ),
    "val-drop4to2": sumo_scenario(
        "sumo-freeflow",
        description="4 lanes, 4200 veh/h, dropping to 2 lanes at 16 m/s at 2.2-2.7 km.",
        lanes=4,
        demand=4200.0,
        bottleneck=Bottleneck(start=2200.0, end=2700.0, lanes=2, speed_limit=16.0),
        warmup=600.0,
        duration=240.0,
    ),
    "val-wave": sumo_scenario(
        "sumo-freeflow",
        description="3 lanes, 4000 veh/h, 20 % trucks, into a zone limited to 6 m/s (1.6-2.4 km).",
        demand=4000.0,
        vehicles=mix(car=0.8, truck=0.2),
        bottleneck=Bottleneck(start=1600.0, end=2400.0, speed_limit=6.0),
        warmup=500.0,
        duration=300.0,
    ),
    "val-faulty-queue": sumo_scenario(
        "sumo-stopgo",
        description="sumo-stopgo seen by faulty detectors: 3 % missed, 3 % false alarms, 3 % "
        "speed error.",
        faults=DetectorFaults(miss_probability=0.03, false_alarm_rate=0.03, velocity_noise=0.03),
    ),
}


# Loops measure speed with an error: a dual loop times the vehicle between its two loops (a few
# per cent), a single loop infers speed from occupancy and an assumed vehicle length (far more).
SPEED_NOISE: dict[str, SumoScenario] = {
    f"{base}-speed{round(100 * noise)}": sumo_scenario(
        base,
        description=f"{base}, speeds measured with a {noise:.0%} error (std), no other fault.",
        faults=DetectorFaults(velocity_noise=noise),
    )
    for base in ("sumo-freeflow", "sumo-dense")
    for noise in (0.03, 0.06, 0.10)
}
SCENARIO_GROUPS = {"main": SUMO_SCENARIOS, "validation": VALIDATION, "speed-noise": SPEED_NOISE}
EVERY_SCENARIO = {name: case for group in SCENARIO_GROUPS.values() for name, case in group.items()}


# A loop's length error: 5-10 % is typical (it is read from occupancy time x speed).
LENGTH_NOISE = 0.07


def with_features(scenario: SumoScenario, length_noise: float) -> SumoScenario:
    """The scenario seen by detectors that report lane, length and class."""
    faults = scenario.faults.model_copy(update={"length_noise": length_noise})
    return SumoScenario.model_validate(
        {**scenario.model_dump(), "features": True, "faults": faults.model_dump()}
    )


def case_file(directory: Path, scenario: str, seed: int) -> Path:
    """Where a simulated case is exported to, and read back from."""
    return directory / f"{scenario}-seed{seed}.csv"


def load_case(
    scenario: str,
    seed: int,
    data: Path | None,
    export: Path | None,
    length_noise: float | None = None,
) -> Detections:
    """The detections of one case: from `data` when given, else simulated by SUMO (with
    detector features when `length_noise` is given)."""
    if data is not None:
        return read_detections_csv(case_file(data, scenario, seed).read_text())
    simulated = EVERY_SCENARIO[scenario]
    if length_noise is not None:
        simulated = with_features(simulated, length_noise)
    detections = run_sumo(simulated, seed=seed)
    if export is not None:
        export.mkdir(parents=True, exist_ok=True)
        case_file(export, scenario, seed).write_text(write_detections_csv(detections))
    return detections


# The column title's suffix for the features a case reports (`--features`, `--lanes-alone`).
FEATURE_SUFFIX = {"all": "", "none": " -f", "lane": " -l"}


def with_reported(detections: Detections, features: str) -> Detections:
    """The case as detectors reporting `features` would see it: all it has, none, or the lane."""
    if features == "none":
        return detections.without_features()
    if features == "lane":
        return detections.only_features("lane")
    return detections


def timed_accuracy(
    detections: Detections, associator: str, timeout: float
) -> tuple[dict[str, float] | None, float]:
    """The associator's metrics and seconds, in a child process killed after `timeout` seconds.

    libsvm has no time limit, and on some traffic the linear SVM does not converge for many
    minutes; such a run is recorded as timed out (None) instead of stalling the table.
    """
    with multiprocessing.get_context("fork").Pool(1) as pool:
        start = time.perf_counter()
        pending = pool.apply_async(_metrics, (detections, associator))
        try:
            metrics = pending.get(timeout)
        except multiprocessing.TimeoutError:
            pool.terminate()
            return None, timeout
        return metrics, time.perf_counter() - start


def _metrics(detections: Detections, associator: str) -> dict[str, float]:
    if associator in REFERENCES:
        groups = REFERENCES[associator](detections.without_labels())
        metrics = score_grouping(groups, detections.target)
    else:
        metrics = associate(detections, associator).metrics
    assert metrics is not None  # SUMO's detections are all labelled
    return metrics.to_dict()


def cell(metrics: list[dict[str, float] | None]) -> str:
    """Mean ± std (worst) of the accuracies, and how many runs timed out."""
    accuracy = [m["accuracy"] for m in metrics if m is not None]
    timed_out = len(metrics) - len(accuracy)
    if not accuracy:
        return f"timed out ({timed_out} of {len(metrics)})"
    text = f"{np.mean(accuracy):.1%} ± {np.std(accuracy):.1%} ({min(accuracy):.0%})"
    return text + (f", {timed_out} of {len(metrics)} timed out" if timed_out else "")


def describe(detections: Detections) -> dict[str, float]:
    """Size of a case: detections, vehicles, and the share of vehicles seen at every sensor."""
    labels = detections.target[detections.target != CLUTTER].astype(str)
    counts = np.unique(labels, return_counts=True)[1]
    return {
        "detections": len(detections),
        "vehicles": int(counts.size),
        "complete_tracks": float(np.mean(counts == detections.sensor_positions.size)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenarios", nargs="+")
    variants = parser.add_mutually_exclusive_group()
    variants.add_argument(
        "--validation", action="store_true", help="Run the VALIDATION variants instead."
    )
    variants.add_argument(
        "--speed-noise", action="store_true", help="Run the SPEED_NOISE variants instead."
    )
    parser.add_argument(
        "--associators",
        nargs="+",
        default=list(ASSOCIATORS),
        help=f"Associators, or the naive references {', '.join(REFERENCES)} "
        "(benchmarks/references.py).",
    )
    parser.add_argument(
        "--features",
        action="store_true",
        help="Detectors report lane, length and class; score with and without them.",
    )
    parser.add_argument(
        "--lanes-alone",
        action="store_true",
        help="With --features, also score the cases with their lane alone (column '-l').",
    )
    parser.add_argument("--length-noise", type=float, default=LENGTH_NOISE)
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument("--export", type=Path, help="Also write the simulated cases' CSVs here.")
    parser.add_argument(
        "--timeout", type=float, default=60.0, help="Seconds an associator may take per case."
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    group = "validation" if args.validation else "speed-noise" if args.speed_noise else "main"
    known = SCENARIO_GROUPS[group]
    args.scenarios = args.scenarios or list(known)
    # With --features, each associator is scored on the same cases without them too ("-f"),
    # and with --lanes-alone on the cases reporting their lane alone ("-l").
    reported = ["all"]
    if args.features:
        reported = ["all", "none", "lane"] if args.lanes_alone else ["all", "none"]
    # The references ignore features: scoring them twice would say nothing.
    columns = [
        (name, features)
        for name in args.associators
        for features in (reported[:1] if name in REFERENCES else reported)
    ]
    titles = [name + FEATURE_SUFFIX[features] for name, features in columns]

    rows: list[dict[str, object]] = []
    sizes: dict[str, list[dict[str, float]]] = {}
    print(f"Accuracy over seeds 0-{args.seeds - 1}: mean ± std (worst)\n")
    print("| scenario | " + " | ".join(titles) + " |")
    print("|---" * (len(titles) + 1) + "|")
    noise = args.length_noise if args.features else None
    for scenario in args.scenarios:
        scores: dict[str, list[dict[str, float] | None]] = {t: [] for t in titles}
        seconds: dict[str, list[float]] = {t: [] for t in titles}
        for seed in range(args.seeds):
            detections = load_case(scenario, seed, args.data, args.export, noise)
            sizes.setdefault(scenario, []).append(describe(detections))
            for (name, features), title in zip(columns, titles, strict=True):
                case = with_reported(detections, features)
                metrics, spent = timed_accuracy(case, name, args.timeout)
                scores[title].append(metrics)
                seconds[title].append(spent)
        cells = []
        for (name, features), title in zip(columns, titles, strict=True):
            rows.append(
                {
                    "scenario": scenario,
                    "associator": name,
                    "features": bool(with_reported(detections, features).features),
                    "reported": list(with_reported(detections, features).features),
                    "metrics": scores[title],
                    "seconds": seconds[title],
                }
            )
            cells.append(cell(scores[title]))
        print(f"| {scenario} | " + " | ".join(cells) + " |", flush=True)

    print("\n| scenario | detections | vehicles | seen at every sensor |\n|---|---|---|---|")
    for scenario, cases in sizes.items():
        mean = {key: float(np.mean([c[key] for c in cases])) for key in cases[0]}
        print(
            f"| {scenario} | {mean['detections']:.0f} | {mean['vehicles']:.0f} | "
            f"{mean['complete_tracks']:.0%} |"
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "seeds": args.seeds,
                "length_noise": noise,
                "timeout_seconds": args.timeout,
                "scenarios": {
                    name: {"description": known[name].description, "cases": sizes[name]}
                    for name in args.scenarios
                },
                "rows": rows,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
