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

`--clock` sets the sensors' clocks off before every associator sees a case (`with_clock`):
`late2` puts the middle sensor's clock 2 s late, `early2` early, and `spread1` offsets every
sensor's clock by a normal draw of 1 s (std; drawn from the seed, the same for every
associator); any number of seconds may follow the word, and `first` or `last` after it moves
the first or last sensor's clock instead of the middle one's (`late3600last`). `step20` has
the middle sensor's clock jump 20 s late at the batch's middle time, `drift10` drift to 10 s
late by its end, `saw10` drift to 10 s late by the middle time, be set right there and drift
to 10 s late again by the end (a clock that its time server corrects now and then), and
`jitter0.5` moves every detection's time by its own normal draw (0.5 s
std: a gateway that stamps reports as it receives them). Field sensors that no GPS or NTP
keeps in step drift by seconds; a time zone or daylight saving time set wrongly puts one an
hour off.

`--quiet` has the middle sensor stop reporting early (`firstN`: it keeps its first N reports)
or start late (`lastN`: its last N), as a detector that fails, loses power or comes back
online part-way through a batch does (`with_quiet`).

`--speed-factor F` has the middle sensor read every speed F times what it is (`0.7first`,
`1.4last`: the first or last sensor), as a single loop does whose assumed vehicle length is off
(`with_speed_factor`).

`--time-step S` stamps every detection to the nearest S seconds, and `--whole-speeds kmh` (or
`mph`) reads every speed to a whole km/h (mile an hour), as many field detectors and traffic
controllers report them (`with_readings`).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import multiprocessing
import re
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from roadlink.association import associate
from roadlink.association.associators import ASSOCIATORS
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.detections import CLUTTER, Detections
from roadlink.association.scores import score_grouping
from roadlink.simulation.sumo import (
    SumoScenario,
    run_sumo,
)

try:
    from benchmarks.references import REFERENCES
    from benchmarks.sumo_scenarios import EVERY_SCENARIO, SCENARIO_GROUPS, SPEED_NOISE
except ModuleNotFoundError:  # run as a script (python benchmarks/sumo_accuracy.py): its folder
    from references import REFERENCES  # type: ignore[no-redef]  # is on the path
    from sumo_scenarios import (  # type: ignore[no-redef]
        EVERY_SCENARIO,
        SCENARIO_GROUPS,
        SPEED_NOISE,
    )

__all__ = ["EVERY_SCENARIO", "LENGTH_NOISE", "SCENARIO_GROUPS", "SPEED_NOISE", "load_case"]

RESULTS = Path(__file__).parent / "results" / "sumo_accuracy.json"


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


CLOCK = re.compile(r"(late|early|spread|step|drift|saw|jitter)(\d+(?:\.\d+)?)(first|last)?")


def parse_clock(clock: str) -> tuple[str, float, str | None]:
    """`--clock`'s value as (kind, seconds, the sensor: 'first', 'last' or None for the middle);
    ValueError saying what is expected where it is none."""
    match = CLOCK.fullmatch(clock)
    if match is None:
        raise ValueError(
            "expected lateS, earlyS, stepS, driftS, sawS, spreadS or jitterS (S seconds), "
            f"got {clock!r}"
        )
    kind, seconds, which = match.group(1), float(match.group(2)), match.group(3)
    if kind in ("spread", "jitter") and which is not None:
        raise ValueError(f"{kind}S moves every sensor's clock, got {clock!r}")
    return kind, seconds, which


def with_clock(detections: Detections, clock: str | None, seed: int) -> Detections:
    """The case as sensors whose clocks are off would report it (`--clock`): `lateS` / `earlyS`
    shift the middle sensor's timestamps by S seconds (`lateSfirst`, `lateSlast`: the first or
    last sensor's), `stepS` those after the batch's middle time alone (a clock that jumped S
    seconds late while it reported), `driftS` by a share of S growing from none at the batch's
    first time to all of it at its last (a clock running fast), `sawS` by such a share growing
    to S by the batch's middle time and again from none to S by its end (a fast clock set right
    at the middle), `spreadS` every sensor's by a
    normal draw of S seconds (std) from `seed`, and `jitterS` every detection's by its own
    (a gateway stamping each report when it receives it); None leaves the case as it is."""
    if clock is None:
        return detections
    kind, seconds, which = parse_clock(clock)
    positions = np.unique(detections.position)
    if kind == "jitter":
        noise = np.random.default_rng(seed).normal(0.0, seconds, len(detections))
        return dataclasses.replace(detections, timestamp=detections.timestamp + noise)
    if kind == "spread":
        offsets = np.random.default_rng(seed).normal(0.0, seconds, positions.size)
    else:
        offsets = np.zeros(positions.size)
        sensor = {"first": 0, "last": -1, None: positions.size // 2}[which]
        offsets[sensor] = -seconds if kind == "early" else seconds
    shift = offsets[np.searchsorted(positions, detections.position)]
    if kind == "step":
        shift = np.where(detections.timestamp > np.median(detections.timestamp), shift, 0.0)
    if kind in ("drift", "saw"):
        first, last = detections.timestamp.min(), detections.timestamp.max()
        share = (detections.timestamp - first) / max(last - first, 1e-9)
        shift = shift * (share if kind == "drift" else (2.0 * share) % 1.0)
    return dataclasses.replace(detections, timestamp=detections.timestamp + shift)


QUIET = re.compile(r"(first|last)(\d+)")


def with_quiet(detections: Detections, quiet: str | None) -> Detections:
    """The case as a middle sensor that stopped reporting early (`firstN`: its first N reports
    kept) or started late (`lastN`) would report it (`--quiet`); None leaves it as it is."""
    if quiet is None:
        return detections
    kind, keep = parse_quiet(quiet)
    positions = np.unique(detections.position)
    at = np.flatnonzero(detections.position == positions[positions.size // 2])
    by_time = at[np.argsort(detections.timestamp[at], kind="stable")]
    dropped = by_time[keep:] if kind == "first" else by_time[: max(by_time.size - keep, 0)]
    return detections.take(np.setdiff1d(np.arange(len(detections)), dropped))


def parse_quiet(quiet: str) -> tuple[str, int]:
    """`--quiet`'s value as ('first' or 'last', the reports kept)."""
    match = QUIET.fullmatch(quiet)
    if match is None:
        raise ValueError(f"expected firstN or lastN (N reports), got {quiet!r}")
    return match.group(1), int(match.group(2))


SPEED_FACTOR = re.compile(r"(\d+(?:\.\d+)?)(first|last)?")


def with_speed_factor(detections: Detections, factor: str | None) -> Detections:
    """The case as a middle sensor (or the first or last: `0.7first`) reading every speed the
    `factor` times it is would report it (`--speed-factor`); None leaves it as it is."""
    if factor is None:
        return detections
    times, which = parse_speed_factor(factor)
    positions = np.unique(detections.position)
    sensor = {"first": 0, "last": -1, None: positions.size // 2}[which]
    at = detections.position == positions[sensor]
    velocity = np.where(at, times * detections.velocity, detections.velocity)
    return dataclasses.replace(detections, velocity=velocity)


def parse_speed_factor(factor: str) -> tuple[float, str | None]:
    """`--speed-factor`'s value as (the factor, the sensor: 'first', 'last' or None for the
    middle)."""
    match = SPEED_FACTOR.fullmatch(factor)
    if match is None or float(match.group(1)) <= 0:
        raise ValueError(f"expected F, Ffirst or Flast (F > 0), got {factor!r}")
    return float(match.group(1)), match.group(2)


def checked(parse: Callable[[str], object]) -> Callable[[str], str]:
    """An option's argparse type: its value checked by `parse` before any case is simulated
    (its error said as argparse says one), and kept as given."""

    def check(value: str) -> str:
        try:
            parse(value)
        except ValueError as error:
            raise argparse.ArgumentTypeError(str(error)) from None
        return value

    return check


# A speed in m/s is this many of each unit (`--whole-speeds`).
SPEED_UNITS = {"kmh": 3.6, "mph": 3600.0 / 1609.344}


def with_readings(
    detections: Detections, time_step: float | None, speed_unit: str | None
) -> Detections:
    """The case as detectors that stamp times to the nearest `time_step` seconds and read speeds
    to a whole `speed_unit` (SPEED_UNITS; at least one) would report it; None leaves either as
    it is."""
    timestamp, velocity = detections.timestamp, detections.velocity
    if time_step is not None:
        timestamp = np.round(timestamp / time_step) * time_step
    if speed_unit is not None:
        per_unit = SPEED_UNITS[speed_unit]
        velocity = np.maximum(np.round(velocity * per_unit), 1.0) / per_unit
    return dataclasses.replace(detections, timestamp=timestamp, velocity=velocity)


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
    minutes; such a run is recorded as timed out (None) instead of stalling the table. The child
    is spawned, not forked: detections read by the CSV reader (`--data`) hold polars columns, and
    a child forked from a process whose polars thread pool is running hangs in it (every case
    of a `--data` run timed out).
    """
    with multiprocessing.get_context("spawn").Pool(1) as pool:
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
    variants.add_argument(
        "--holdout", action="store_true", help="Run the HOLDOUT queues instead (never tune on)."
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
    parser.add_argument(
        "--clock",
        type=checked(parse_clock),
        help="Sensors' clocks off: lateS, earlyS (the middle sensor, S seconds; lateSfirst, "
        "lateSlast: the first or last), stepS (the middle sensor S seconds late from the "
        "batch's middle time on), driftS (the middle sensor's clock drifting to S seconds late "
        "by the batch's end), sawS (drifting to S seconds late by the batch's middle time, set "
        "right there, and again by its end), spreadS (every sensor, S seconds std) or jitterS "
        "(every detection, S seconds std).",
    )
    parser.add_argument(
        "--quiet",
        type=checked(parse_quiet),
        help="The middle sensor stops reporting early (firstN: keeps its first N reports) or "
        "starts late (lastN).",
    )
    parser.add_argument(
        "--speed-factor",
        type=checked(parse_speed_factor),
        help="The middle sensor reads every speed F times what it is (Ffirst, Flast: the first "
        "or last sensor).",
    )
    parser.add_argument(
        "--time-step", type=float, help="Stamp every time to the nearest this many seconds."
    )
    parser.add_argument(
        "--whole-speeds", choices=sorted(SPEED_UNITS), help="Read every speed to a whole unit."
    )
    parser.add_argument("--length-noise", type=float, default=LENGTH_NOISE)
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument("--export", type=Path, help="Also write the simulated cases' CSVs here.")
    parser.add_argument(
        "--timeout", type=float, default=60.0, help="Seconds an associator may take per case."
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    group = (
        "validation"
        if args.validation
        else "speed-noise"
        if args.speed_noise
        else "holdout"
        if args.holdout
        else "main"
    )
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
            detections = with_quiet(with_clock(detections, args.clock, seed), args.quiet)
            detections = with_speed_factor(detections, args.speed_factor)
            detections = with_readings(detections, args.time_step, args.whole_speeds)
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
                "clock": args.clock,
                "quiet": args.quiet,
                "speed_factor": args.speed_factor,
                "time_step": args.time_step,
                "whole_speeds": args.whole_speeds,
                "timeout_seconds": args.timeout,
                "scenarios": {
                    name: {"description": EVERY_SCENARIO[name].description, "cases": sizes[name]}
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
