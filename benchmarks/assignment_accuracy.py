"""Accuracy of the `assignment` associator on the simulator's presets and on harder traffic.

Each case is simulated with seeds 0 .. N-1 and grouped with the default parameters; the table
gives the mean, the standard deviation and the worst seed's accuracy (the paper's figure, see
service/roadlink/association/scores.py). Writes benchmarks/results/assignment_accuracy.json.

    python benchmarks/assignment_accuracy.py --seeds 20
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from roadlink.association import associate
from roadlink.simulation import preset, simulate

RESULTS = Path(__file__).parent / "results" / "assignment_accuracy.json"
FAULTS: dict[str, object] = {"miss_probability": 0.05, "false_alarm_rate": 0.05}
IRREGULAR = [0.0, 40.0, 260.0, 300.0, 620.0, 700.0, 1150.0, 1180.0, 1500.0, 1530.0]

CASES: list[tuple[str, str, dict[str, object]]] = [
    ("large", "large", {}),
    ("medium", "medium", {}),
    ("small", "small", {}),
    ("large, 5% missed + 5% false alarms", "large", FAULTS),
    ("medium, 5% missed + 5% false alarms", "medium", FAULTS),
    ("small, 5% missed + 5% false alarms", "small", FAULTS),
    ("congested (120 targets, slow zone x0.5)", "congested", {}),
    ("congested, 5% missed + 5% false alarms", "congested", FAULTS),
    ("congested, 5% duplicated", "congested", {"duplicate_probability": 0.05}),
    (
        "congested, slow zone x0.1 (stop-and-go)",
        "congested",
        {"slow_zone": {"start": 400.0, "end": 600.0, "speed_factor": 0.1}},
    ),
    ("congested, velocity fluctuation 15%", "congested", {"velocity_fluctuation": 0.15}),
    (
        "congested, noise: 2% speed, 0.05 s time",
        "congested",
        {"velocity_noise": 0.02, "timestamp_noise": 0.05},
    ),
    ("medium, irregular sensor spacing", "medium", {"sensor_positions": IRREGULAR}),
    ("medium, velocity fluctuation 15%", "medium", {"velocity_fluctuation": 0.15}),
    ("medium, 5% duplicated", "medium", {"duplicate_probability": 0.05}),
]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=20)
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    rows = []
    print(f"Accuracy of 'assignment' over seeds 0-{args.seeds - 1}: mean ± std (worst)\n")
    print("| case | accuracy | seconds per run |")
    print("|---|---|---|")
    for label, name, overrides in CASES:
        scores, seconds = [], []
        for seed in range(args.seeds):
            detections = simulate(preset(name, **overrides), seed=seed).detections
            start = time.perf_counter()
            result = associate(detections, "assignment")
            seconds.append(time.perf_counter() - start)
            assert result.metrics is not None
            scores.append(result.metrics.accuracy)
        mean, std, worst = float(np.mean(scores)), float(np.std(scores)), float(np.min(scores))
        rows.append({"case": label, "preset": name, "overrides": overrides, "accuracies": scores})
        print(f"| {label} | {mean:.1%} ± {std:.1%} ({worst:.0%}) | {np.median(seconds):.2f} |")
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(json.dumps({"seeds": args.seeds, "rows": rows}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
