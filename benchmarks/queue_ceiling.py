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
- `oracle +features` (cases whose detectors report lane, length and class, `--features`): the
  same, plus each feature's likelihood ratio "same vehicle" against "any vehicle at the far
  sensor", with the true statistics (the length error, lane transitions and class confusion of
  the true pairs), reading against reading: what the features add once the curve is known.
  `assignment` is scored with the features too.

    python benchmarks/queue_ceiling.py --data /work/sumo-data
    python benchmarks/queue_ceiling.py --seeds 5 --scenarios sumo-queue sumo-stopgo
    python benchmarks/queue_ceiling.py --features --data /work/sumo-data-features

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
    from benchmarks.sumo_accuracy import EVERY_SCENARIO, LENGTH_NOISE, load_case
except ModuleNotFoundError:  # run as a script: its folder is on the path
    from references import (  # type: ignore[no-redef]
        chain_groups,
        chained_groups,
        gated_assignment,
    )
    from sumo_accuracy import (  # type: ignore[no-redef]
        EVERY_SCENARIO,
        LENGTH_NOISE,
        load_case,
    )

RESULTS = Path(__file__).parent / "results" / "queue_ceiling.json"
SCENARIOS = ("sumo-queue", "sumo-stopgo", "sumo-bottleneck", "val-queue-irregular")
CURVE_NEIGHBOURS = 7  # each side: the running median is over 15 vehicles
GATE = 9.0  # a link's cost (squared standardised errors) above which both ends stay apart
METHODS = ("floor", "chain", "assignment", "oracle time", "oracle time+speed")
FEATURE_METHODS = (*METHODS, "oracle +features")
# Kernel width of the far sensor's log lengths (as assignment's features use).
LENGTH_KERNEL = 0.03


def oracle_groups(d: Detections, speeds: bool, features: bool = False) -> np.ndarray:
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
        if features:
            cost = cost + _feature_cost(d, a, b, true_a, true_b)
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


def _feature_cost(
    d: Detections, a: np.ndarray, b: np.ndarray, true_a: np.ndarray, true_b: np.ndarray
) -> np.ndarray:
    """-2 log likelihood ratio of every pair's lane, length and class, with the true pairs'
    statistics (a reading a feature lacks adds nothing)."""
    cost = np.zeros((a.size, b.size))
    log_length = np.log(d.length)
    true_difference = log_length[true_b] - log_length[true_a]
    true_difference = true_difference[np.isfinite(true_difference)]
    if true_difference.size > 2:
        spread = max(float(np.std(true_difference)), 1e-3)
        difference = log_length[b][None, :] - log_length[a][:, None]
        same = np.exp(-0.5 * (difference / spread) ** 2) / (np.sqrt(2 * np.pi) * spread)
        far = log_length[b][np.isfinite(log_length[b])]
        kernel = (log_length[b][:, None] - far[None, :]) / LENGTH_KERNEL
        other = np.exp(-0.5 * kernel**2).mean(axis=1) / (np.sqrt(2 * np.pi) * LENGTH_KERNEL)
        ratio = same / np.maximum(other[None, :], 1e-12)
        cost += np.where(np.isfinite(difference), -2.0 * np.log(np.maximum(ratio, 1e-12)), 0.0)
    for values in (d.lane.astype(str), d.vehicle_class.astype(str)):
        cost += _categorical_cost(values, a, b, true_a, true_b)
    return cost


def _categorical_cost(
    values: np.ndarray, a: np.ndarray, b: np.ndarray, true_a: np.ndarray, true_b: np.ndarray
) -> np.ndarray:
    """-2 log(P(b's value | a's, same vehicle) / P(b's value at the far sensor)), from the true
    pairs' transitions (one added to every count)."""
    reported = (values != "-1") & (values != "None")
    kinds = np.unique(values[reported])
    if kinds.size < 2:
        return np.zeros((a.size, b.size))
    index = {kind: k for k, kind in enumerate(kinds)}
    transitions = np.ones((kinds.size, kinds.size))
    for i, j in zip(true_a, true_b, strict=True):
        if reported[i] and reported[j]:
            transitions[index[values[i]], index[values[j]]] += 1
    transitions /= transitions.sum(axis=1, keepdims=True)
    share = np.ones(kinds.size)
    for j in b[reported[b]]:
        share[index[values[j]]] += 1
    share /= share.sum()
    cost = np.zeros((a.size, b.size))
    rows = np.flatnonzero(reported[a])
    cols = np.flatnonzero(reported[b])
    ka = np.array([index[values[i]] for i in a[rows]], dtype=np.int64)
    kb = np.array([index[values[j]] for j in b[cols]], dtype=np.int64)
    cost[np.ix_(rows, cols)] = -2.0 * np.log(transitions[ka][:, kb] / share[kb][None, :])
    return cost


def accuracies(d: Detections) -> dict[str, float]:
    """The accuracy of every method of METHODS (FEATURE_METHODS when the detections report
    features) on one case."""
    blind = d.without_labels()
    grouping = {
        "floor": np.arange(len(d), dtype=np.int64),
        "chain": chain_groups(blind),
        "assignment": associate(d, "assignment").groups,
        "oracle time": oracle_groups(d, speeds=False),
        "oracle time+speed": oracle_groups(d, speeds=True),
    }
    if d.features:
        grouping["oracle +features"] = oracle_groups(d, speeds=True, features=True)
    scores = {name: score_grouping(groups, d.target) for name, groups in grouping.items()}
    return {name: score.accuracy for name, score in scores.items() if score is not None}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument(
        "--features",
        action="store_true",
        help="Cases whose detectors report lane, length (7 %% error) and class.",
    )
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    methods = FEATURE_METHODS if args.features else METHODS
    noise = LENGTH_NOISE if args.features else None
    report: dict[str, dict[str, list[float]]] = {}
    print(f"Accuracy over seeds 0-{args.seeds - 1} (mean)\n")
    print("| scenario | " + " | ".join(methods) + " |")
    print("|---" * (len(methods) + 1) + "|")
    for scenario in args.scenarios:
        if scenario not in EVERY_SCENARIO:
            raise SystemExit(f"unknown scenario '{scenario}'")
        runs = [
            accuracies(load_case(scenario, s, args.data, None, noise)) for s in range(args.seeds)
        ]
        report[scenario] = {name: [run[name] for run in runs] for name in methods}
        cells = [f"{np.mean(report[scenario][name]):.1%}" for name in methods]
        print(f"| {scenario} | " + " | ".join(cells) + " |", flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"seeds": args.seeds, "accuracy": report}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
