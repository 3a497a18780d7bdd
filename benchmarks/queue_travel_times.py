"""What predicts a travel time in a queue: the speeds at the two sensors, or the clock?

On the committed SUMO bottleneck case (tests/data/sumo/sumo-bottleneck.csv, labelled), every
true link between neighbouring sensors is predicted two ways, and the robust spread (1.4826 x
MAD) of the log errors is printed per segment:

- kinematic: `dx * (1 / v_a + 1 / v_b) / 2`, scaled by the segment's median bias (what
  `assignment` starts from; its learned skew and bias do not change the spread much);
- clock: the median log travel time of the NEIGHBOURS links entering the segment just before and
  just after it, never the link itself (a travel time as a smooth function of entry time).

It also draws, for three segments, each true link's travel time against its entry time beside
dx / v_a and dx / v_b (docs/img/queue_travel_times.png). Uses the labels: it measures what the
data hold, not what an associator finds. Run: `python -m benchmarks.queue_travel_times`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import CLUTTER, Detections, FloatArray, IntArray

CASE = Path(__file__).parents[1] / "tests" / "data" / "sumo" / "sumo-bottleneck.csv"
FIGURE = Path(__file__).parents[1] / "docs" / "img" / "queue_travel_times.png"
NEIGHBOURS = 5


def true_links(d: Detections) -> tuple[IntArray, IntArray, IntArray, FloatArray]:
    """Every labelled target's consecutive detections at neighbouring sensors: (a, b, index of
    a's sensor, sensor positions)."""
    positions, sensor = np.unique(d.position, return_inverse=True)
    labels = d.target.astype(str)
    order = np.lexsort((d.timestamp, sensor, labels))
    a, b = order[:-1], order[1:]
    keep = (labels[a] == labels[b]) & (labels[a] != CLUTTER) & (sensor[b] == sensor[a] + 1)
    return a[keep], b[keep], sensor[a[keep]], positions


def robust_spread(values: FloatArray) -> float:
    return float(1.4826 * np.median(np.abs(values - np.median(values))))


def neighbours_median(series: FloatArray, half: int) -> FloatArray:
    """For each element, the median of the `half` elements before and after it (not itself)."""
    padded = np.pad(series, half, mode="edge")
    window = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    return np.median(np.delete(window, half, axis=1), axis=1)


def segment_spreads(d: Detections) -> list[tuple[float, float, float, float, int]]:
    """Per segment: (start, median speed at a, kinematic spread, clock spread, links)."""
    a, b, k, positions = true_links(d)
    rows = []
    for segment in range(positions.size - 1):
        here = k == segment
        if here.sum() < 2 * NEIGHBOURS + 1:
            continue
        ia, ib = a[here], b[here]
        by_entry = np.argsort(d.timestamp[ia], kind="stable")
        ia, ib = ia[by_entry], ib[by_entry]
        gap = positions[segment + 1] - positions[segment]
        log_travel = np.log(d.timestamp[ib] - d.timestamp[ia])
        kinematic = np.log(gap * 0.5 * (1.0 / d.velocity[ia] + 1.0 / d.velocity[ib]))
        rows.append(
            (
                float(positions[segment]),
                float(np.median(d.velocity[ia])),
                robust_spread(log_travel - kinematic),
                robust_spread(log_travel - neighbours_median(log_travel, NEIGHBOURS)),
                int(ia.size),
            )
        )
    return rows


def draw(d: Detections, segments: list[int], out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    a, b, k, positions = true_links(d)
    fig, axes = plt.subplots(len(segments), 1, figsize=(9, 2.6 * len(segments)), sharex=True)
    for ax, segment in zip(np.atleast_1d(axes), segments, strict=True):
        here = k == segment
        gap = positions[segment + 1] - positions[segment]
        entry = d.timestamp[a[here]]
        ax.scatter(entry, d.timestamp[b[here]] - entry, s=6, label="travel time")
        ax.scatter(entry, gap / d.velocity[a[here]], s=6, marker="x", label="dx / v_a")
        ax.scatter(entry, gap / d.velocity[b[here]], s=6, marker="+", label="dx / v_b")
        ax.set_ylim(0, 90)
        ax.set_ylabel("s")
        ax.set_title(f"{positions[segment]:.0f} m -> {positions[segment + 1]:.0f} m", fontsize=9)
    np.atleast_1d(axes)[0].legend(fontsize=8, loc="upper right")
    np.atleast_1d(axes)[-1].set_xlabel("time the link entered the segment (s)")
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=80)
    plt.close(fig)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--case", type=Path, default=CASE)
    parser.add_argument("--plot", type=Path, default=FIGURE)
    parser.add_argument("--segments", type=int, nargs="+", default=[0, 4, 7])
    args = parser.parse_args()
    d = read_detections_csv(args.case.read_text())
    print("| segment from | median speed | kinematic spread | clock spread | links |")
    print("|---:|---:|---:|---:|---:|")
    for start, speed, kinematic, clock, links in segment_spreads(d):
        print(f"| {start:.0f} m | {speed:.1f} m/s | {kinematic:.3f} | {clock:.3f} | {links} |")
    draw(d, args.segments, args.plot)
    print(f"\nwritten to {args.plot}")


if __name__ == "__main__":
    main()
