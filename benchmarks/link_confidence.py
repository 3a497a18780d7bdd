"""How far `assignment`'s link confidences can be trusted, on SUMO traffic: calibration, and the
trade-off a `min_confidence` threshold makes between links correct and links false.

For every scenario, over seeds 0 .. N-1, the links of `assignment`'s targets (consecutive
detections of a target) are compared with the truth. Two tables:
- calibration: per confidence bin, how many links fall in it and the share of them that is right
  (a calibrated confidence of 0.8 is right 80 % of the time);
- trade-off, as the vehicle re-identification literature reports it: for each threshold, the
  share of the true links (pairs of consecutive detections of one vehicle) that are kept and
  right ("correct"), and the share of the kept links that are wrong ("false").

    python benchmarks/link_confidence.py --data /work/sumo-data       # exported cases, no SUMO
    python benchmarks/link_confidence.py --seeds 5 --scenarios sumo-dense sumo-queue

Writes benchmarks/results/link_confidence.json.
"""

from __future__ import annotations

import argparse
import itertools
import json
from pathlib import Path
from typing import Any

import numpy as np

from roadlink.association import associate
from roadlink.association.detections import CLUTTER, Detections

try:
    from benchmarks.sumo_accuracy import EVERY_SCENARIO, load_case
    from benchmarks.sumo_scenarios import SUMO_SCENARIOS, VALIDATION
except ModuleNotFoundError:  # run as a script: its folder is on the path
    from sumo_accuracy import EVERY_SCENARIO, load_case  # type: ignore[no-redef]
    from sumo_scenarios import SUMO_SCENARIOS, VALIDATION  # type: ignore[no-redef]

RESULTS = Path(__file__).parent / "results" / "link_confidence.json"
BINS = (0.0, 0.5, 0.7, 0.9, 0.99, 1.0)
THRESHOLDS = (0.0, 0.5, 0.7, 0.9, 0.99)


def links(detections: Detections) -> tuple[np.ndarray, np.ndarray, int]:
    """The confidence of every link `assignment` made, whether it is right, and how many true
    links (consecutive detections of one vehicle) there are."""
    result = associate(detections, "assignment")
    assert result.link_confidence is not None
    groups, d = result.groups, result.detections
    assigned = np.flatnonzero(groups >= 0)
    order = assigned[np.lexsort((d.position[assigned], groups[assigned]))]
    same = groups[order[1:]] == groups[order[:-1]]
    before, after = order[:-1][same], order[1:][same]
    right = (d.target[before] == d.target[after]) & (d.target[after] != CLUTTER)
    labels = d.target[d.target != CLUTTER].astype(str)
    true_links = len(labels) - np.unique(labels).size
    return result.link_confidence[after], right, true_links


def tables(confidence: np.ndarray, right: np.ndarray, true_links: int) -> dict[str, Any]:
    """The calibration and trade-off tables of one scenario's links (all seeds pooled)."""
    calibration = []
    for low, high in itertools.pairwise(BINS):
        inside = (confidence >= low) & ((confidence < high) | (high == 1.0))
        calibration.append(
            {
                "bin": [low, high],
                "links": int(inside.sum()),
                "right": float(right[inside].mean()) if inside.any() else None,
            }
        )
    trade_off = []
    for threshold in THRESHOLDS:
        kept = confidence >= threshold
        trade_off.append(
            {
                "min_confidence": threshold,
                "correct": float((kept & right).sum() / true_links) if true_links else None,
                "false": float((kept & ~right).sum() / kept.sum()) if kept.any() else None,
            }
        )
    return {
        "links": int(confidence.size),
        "right": float(right.mean()) if right.size else None,
        "mean_confidence": float(confidence.mean()) if confidence.size else None,
        "calibration": calibration,
        "trade_off": trade_off,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenarios", nargs="+", default=[*SUMO_SCENARIOS, *VALIDATION])
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()

    report: dict[str, object] = {}
    print("Links correct / false at each min_confidence (share of true links kept and right;")
    print(f"share of kept links wrong), seeds 0-{args.seeds - 1}\n")
    print("| scenario | mean confidence / right | " + " | ".join(map(str, THRESHOLDS)) + " |")
    print("|---" * (len(THRESHOLDS) + 2) + "|")
    for scenario in args.scenarios:
        if scenario not in EVERY_SCENARIO:
            raise SystemExit(f"unknown scenario '{scenario}'")
        found = [links(load_case(scenario, seed, args.data, None)) for seed in range(args.seeds)]
        confidence = np.concatenate([f[0] for f in found])
        right = np.concatenate([f[1] for f in found])
        summary = tables(confidence, right, sum(f[2] for f in found))
        report[scenario] = summary
        cells = [f"{row['correct']:.0%} / {row['false']:.0%}" for row in summary["trade_off"]]
        print(
            f"| {scenario} | {summary['mean_confidence']:.2f} / {summary['right']:.2f} | "
            + " | ".join(cells)
            + " |",
            flush=True,
        )
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"seeds": args.seeds, "scenarios": report}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
