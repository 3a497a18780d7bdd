"""What timestamps and speeds can tell in a queue: `assignment` beside a floor and two ceilings.

In a queue, spot speeds say little about a vehicle (0.1-3 m/s at every sensor), and travel
times of 100 s or more are many headways long, so a link shifted by one vehicle fits about as
well as the true one. How much can any method get from timestamps and speeds alone? Per
scenario, over seeds 0 .. N-1:

- `floor`: every detection a target of its own; accuracy is then vehicles / detections (the
  Hungarian matching gives each vehicle one detection). A grouping at the floor links nothing.
- `chain`: the naive reference of benchmarks/references.py.
- `assignment`: the associator, at its defaults.
- `oracle time`: the true travel-time curve of each segment is *given* (a running median of the
  true travel times over the 15 nearest vehicles, by the time they passed the upstream sensor),
  and each segment is matched by one assignment on the error against it, with the spread of the
  true errors; links chained into targets. No method without labels knows that curve.
- `oracle time+speed`: the same, plus the kinematic ratio of both ends' speeds, costed by its
  true regression on the travel-time error (what speeds add once the curve is known).

    python benchmarks/queue_ceiling.py --data /work/sumo-data
    python benchmarks/queue_ceiling.py --seeds 5 --scenarios sumo-queue sumo-stopgo

Writes benchmarks/results/queue_ceiling.json.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path

import numpy as np

from roadlink.association import associate
from roadlink.association.detections import CLUTTER, Detections
from roadlink.association.scores import score_grouping

try:
    from benchmarks.references import chain_groups, chained_groups, gated_assignment
    from benchmarks.sumo_accuracy import EVERY_SCENARIO, load_case
except ModuleNotFoundError:  # run as a script: its folder is on the path
    from references import (  # type: ignore[no-redef]
        chain_groups,
        chained_groups,
        gated_assignment,
    )
    from sumo_accuracy import EVERY_SCENARIO, load_case  # type: ignore[no-redef]

RESULTS = Path(__file__).parent / "results" / "queue_ceiling.json"
SCENARIOS = ("sumo-queue", "sumo-stopgo", "sumo-bottleneck", "val-queue-irregular")
CURVE_NEIGHBOURS = 7  # each side: the running median is over 15 vehicles
GATE = 9.0  # a link's cost (squared standardised errors) above which both ends stay apart
METHODS = ("floor", "chain", "assignment", "oracle time", "oracle time+speed")


def oracle_groups(d: Detections, speeds: bool) -> np.ndarray:
    """Segments matched against their true travel-time curves (see the module's docstring)."""
    positions = np.unique(d.position)
    labels = d.target.astype(str)
    successor = np.full(len(d), -1, dtype=np.int64)
    for upstream, downstream in itertools.pairwise(positions):
        a = np.flatnonzero(d.position == upstream)
        b = np.flatnonzero(d.position == downstream)
        partner = {label: j for j, label in zip(b, labels[b], strict=True) if label != CLUTTER}
        true_a = np.array([i for i in a if labels[i] in partner], dtype=np.int64)
        if true_a.size < 3:
            continue
        true_b = np.array([partner[labels[i]] for i in true_a], dtype=np.int64)
        order = np.argsort(d.timestamp[true_a])
        true_a, true_b = true_a[order], true_b[order]
        passed = d.timestamp[true_a]
        travel = d.timestamp[true_b] - passed
        curve = np.array(
            [
                np.median(travel[max(0, k - CURVE_NEIGHBOURS) : k + CURVE_NEIGHBOURS + 1])
                for k in range(travel.size)
            ]
        )
        spread = max(float(np.std(travel - curve)), 0.2)
        observed = d.timestamp[b][None, :] - d.timestamp[a][:, None]
        error = observed - np.interp(d.timestamp[a], passed, curve)[:, None]
        cost = (error / spread) ** 2
        if speeds:
            cost = cost + _speed_cost(d, a, b, upstream, downstream, true_a, true_b, error)
        cost = np.where((observed > 0) & np.isfinite(cost), cost, np.inf)
        rows, cols = gated_assignment(cost, alone=GATE / 2, gate=GATE)
        successor[a[rows]] = b[cols]
    return chained_groups(successor)


def _speed_cost(
    d: Detections,
    a: np.ndarray,
    b: np.ndarray,
    upstream: float,
    downstream: float,
    true_a: np.ndarray,
    true_b: np.ndarray,
    error: np.ndarray,
) -> np.ndarray:
    """The kinematic log ratio's squared error against its true regression on the travel-time
    error, standardised by the true residual spread."""

    def ratio(i: np.ndarray, j: np.ndarray, travel: np.ndarray) -> np.ndarray:
        mean_speed = 0.5 * (d.velocity[i] + d.velocity[j])
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.asarray(np.log(travel * mean_speed / (downstream - upstream)))

    true_travel = d.timestamp[true_b] - d.timestamp[true_a]
    true_error = true_travel - np.median(true_travel)
    slope, intercept = np.polyfit(true_error, ratio(true_a, true_b, true_travel), 1)
    spread = max(float(np.std(ratio(true_a, true_b, true_travel) - slope * true_error)), 1e-3)
    observed = d.timestamp[b][None, :] - d.timestamp[a][:, None]
    pairs = ratio(a[:, None], b[None, :], observed)
    return np.asarray(((pairs - intercept - slope * error) / spread) ** 2)


def accuracies(d: Detections) -> dict[str, float]:
    """The accuracy of every method of METHODS on one case."""
    blind = d.without_labels()
    grouping = {
        "floor": np.arange(len(d), dtype=np.int64),
        "chain": chain_groups(blind),
        "assignment": associate(d, "assignment").groups,
        "oracle time": oracle_groups(d, speeds=False),
        "oracle time+speed": oracle_groups(d, speeds=True),
    }
    scores = {name: score_grouping(groups, d.target) for name, groups in grouping.items()}
    return {name: score.accuracy for name, score in scores.items() if score is not None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    report: dict[str, dict[str, list[float]]] = {}
    print(f"Accuracy over seeds 0-{args.seeds - 1} (mean)\n")
    print("| scenario | " + " | ".join(METHODS) + " |")
    print("|---" * (len(METHODS) + 1) + "|")
    for scenario in args.scenarios:
        if scenario not in EVERY_SCENARIO:
            raise SystemExit(f"unknown scenario '{scenario}'")
        runs = [accuracies(load_case(scenario, s, args.data, None)) for s in range(args.seeds)]
        report[scenario] = {name: [run[name] for run in runs] for name in METHODS}
        cells = [f"{np.mean(report[scenario][name]):.1%}" for name in METHODS]
        print(f"| {scenario} | " + " | ".join(cells) + " |", flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"seeds": args.seeds, "accuracy": report}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
