"""How the `assignment` associator scales: seconds and peak memory from 10^3 to 10^6 detections.

Every size is run in a fresh subprocess (so one size's memory cannot flatter the next): the
detections are simulated first (not timed), then grouped `--repeats` times; the time is the median
and the peak memory is measured by tracemalloc on one further run (numpy reports its buffers to
tracemalloc, so this is the associator's own allocation, excluding the interpreter and the input).

Traffic: 50 sensors 100 m apart, targets entering at one a second at 20-40 m/s with the paper's
velocity fluctuation, so the density (and the overtaking) is the same at every size and only the
length of the observation grows, as when a deployment's time window grows.

    python benchmarks/associator_scaling.py            # 10^3 .. 10^6, writes the JSON
    python benchmarks/associator_scaling.py --max-detections 100000 --repeats 5
"""

from __future__ import annotations

import argparse
import json
import platform
import statistics
import subprocess
import sys
import time
import tracemalloc
from pathlib import Path

SENSORS = 50
RESULTS = Path(__file__).parent / "results" / "associator_scaling.json"


def measure(n_targets: int, repeats: int, seed: int) -> dict[str, float | int]:
    """Simulate, then time and trace the associator on one size (run inside the subprocess)."""
    from roadlink.association.associators.assignment import AssignmentAssociator
    from roadlink.association.scores import score_grouping
    from roadlink.simulation import SimulationConfig, simulate

    config = SimulationConfig(
        n_targets=n_targets,
        sensor_positions=[100.0 * i for i in range(SENSORS)],
        velocity_range=(20.0, 40.0),
        start_time_range=(0.0, float(n_targets)),
    )
    labelled = simulate(config, seed=seed).detections
    detections = labelled.without_labels()
    associator = AssignmentAssociator()
    seconds = []
    groups = None
    for _ in range(repeats):
        start = time.perf_counter()
        groups = associator.group(detections)
        seconds.append(time.perf_counter() - start)
    tracemalloc.start()
    associator.group(detections)
    _, peak = tracemalloc.get_traced_memory()
    tracemalloc.stop()
    assert groups is not None
    metrics = score_grouping(groups, labelled.target)
    assert metrics is not None
    return {
        "n_targets": n_targets,
        "n_detections": len(detections),
        "seconds": statistics.median(seconds),
        "seconds_min": min(seconds),
        "peak_mib": peak / 2**20,
        "accuracy": metrics.accuracy,
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--max-detections", type=int, default=1_000_000)
    parser.add_argument("--repeats", type=int, default=3, help="Timed runs per size (median).")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--output", type=Path, default=RESULTS)
    parser.add_argument("--one", type=int, help=argparse.SUPPRESS)  # internal: one size
    args = parser.parse_args()
    if args.one is not None:
        print(json.dumps(measure(args.one, args.repeats, args.seed)))
        return

    rows = []
    print(f"{'detections':>11} {'targets':>8} {'seconds':>9} {'peak MiB':>9} {'accuracy':>9}")
    n_detections = 1_000
    while n_detections <= args.max_detections:
        n_targets = n_detections // SENSORS
        command = [sys.executable, __file__, "--one", str(n_targets)]
        command += ["--repeats", str(args.repeats), "--seed", str(args.seed)]
        done = subprocess.run(
            command,
            check=True,
            capture_output=True,
            text=True,
        )
        row = json.loads(done.stdout.strip().splitlines()[-1])
        rows.append(row)
        print(
            f"{row['n_detections']:>11,} {row['n_targets']:>8,} {row['seconds']:>9.2f} "
            f"{row['peak_mib']:>9.1f} {row['accuracy']:>9.2%}",
            flush=True,
        )
        n_detections *= 10
    args.output.parent.mkdir(parents=True, exist_ok=True)
    args.output.write_text(
        json.dumps(
            {
                "associator": "assignment",
                "sensors": SENSORS,
                "repeats": args.repeats,
                "machine": {"platform": platform.platform(), "processor": platform.processor()},
                "python": platform.python_version(),
                "rows": rows,
            },
            indent=2,
        )
        + "\n"
    )
    print(f"written to {args.output}")


if __name__ == "__main__":
    main()
