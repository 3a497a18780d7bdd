"""What the measured vehicle length (`use_length`) does for the paper's associators.

The paper's presets are simulated with vehicle lengths (a car / van / truck / bus mix, measured
with `--length-noise`), seeds 0 .. N-1, and each associator groups every data set twice, with its
default parameters and with `use_length`; the same data sets both times, so the gain is paired.
`--missing` drops that share of the measured lengths at random (they are then imputed). Writes
benchmarks/results/length_feature.json.

    python benchmarks/length_feature.py --seeds 100 --associator kmeans --associator kmeans++
"""

from __future__ import annotations

import argparse
import dataclasses
import json
from pathlib import Path

import numpy as np

from roadlink.association import Detections, associate
from roadlink.simulation import preset, simulate

RESULTS = Path(__file__).parent / "results" / "length_feature.json"
PRESETS = ("large", "medium", "small")
PAPER = ("kmeans", "kmeans++", "svm-linear", "svm-quadratic")


def data_sets(name: str, args: argparse.Namespace) -> list[Detections]:
    config = preset(name, vehicle_lengths=True, length_noise=args.length_noise)
    drop = np.random.default_rng(0)
    out = []
    for seed in range(args.seeds):
        d = simulate(config, seed=seed).detections
        missing = drop.random(len(d)) < args.missing
        out.append(dataclasses.replace(d, length=np.where(missing, np.nan, d.length)))
    return out


def accuracies(data: list[Detections], associator: str, params: dict[str, object]) -> list[float]:
    scores = []
    for d in data:
        metrics = associate(d, associator, params).metrics
        assert metrics is not None  # simulated detections are labelled
        scores.append(metrics.accuracy)
    return scores


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--associator", action="append", choices=PAPER)
    parser.add_argument("--length-noise", type=float, default=0.05)
    parser.add_argument("--missing", type=float, default=0.0)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    rows = []
    print(
        f"Accuracy over seeds 0-{args.seeds - 1}, lengths measured with {args.length_noise:.0%} "
        f"error, {args.missing:.0%} missing: median (mean)\n"
    )
    print("| preset | associator | without length | use_length | mean gain (points) | seeds +/- |")
    print("|---|---|---|---|---|---|")
    for name in PRESETS:
        data = data_sets(name, args)
        for associator in args.associator or PAPER:
            without = accuracies(data, associator, {})
            with_length = accuracies(data, associator, {"use_length": True})
            gain = np.subtract(with_length, without)
            rows.append(
                {
                    "preset": name,
                    "associator": associator,
                    "without": without,
                    "use_length": with_length,
                }
            )
            print(
                f"| {name} | {associator} | {np.median(without):.1%} ({np.mean(without):.1%}) "
                f"| {np.median(with_length):.1%} ({np.mean(with_length):.1%}) "
                f"| {100 * gain.mean():+.1f} | {np.sum(gain > 0)}/{np.sum(gain < 0)} |",
                flush=True,
            )
    settings = {"seeds": args.seeds, "length_noise": args.length_noise, "missing": args.missing}
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({**settings, "rows": rows}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
