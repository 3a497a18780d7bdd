"""Lane order in queues: `assignment` with and without its lane-order anchors, and lane order alone.

A vehicle that keeps its lane between two sensors cannot pass another that keeps it too: lane by
lane, a queue is first in, first out. On the SUMO queue cases this holds for 94-100 % of the
vehicles that keep their lane (sumo-bottleneck, seed 0), where the order over all lanes together
is kept by only 50-60 %. `assignment` uses it where detectors report lane and length (its lane
anchors, `assignment/anchors.py`). Per segment (the road between two neighbouring sensors), the
share of true links each method makes, and the accuracy of its grouping:

- `assignment, no lane anchors`: the associator with `lane_anchors` off.
- `assignment`: the associator at its defaults (lane anchors on).
- `lane order, true curves`: lane order alone, given what no method without labels knows. Each
  lane's upstream and downstream detections are aligned in time order (a monotone alignment:
  any detection may stay unpaired, a lane changer or a vehicle outside the time window), each
  pair scored by the log-likelihood ratio of its travel time against that lane's *true*
  travel-time curve (a running median over the true links of the vehicles that kept the lane)
  and of its two lengths; the detections left over are matched by one assignment against the
  whole segment's curve. Speeds are not used.

    python benchmarks/lane_order.py --data /work/sumo-data-features --seeds 5

Cases must report lane and length (`benchmarks/sumo_accuracy.py --features --export DIR`).
Writes benchmarks/results/lane_order.json.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
from scipy.optimize import linear_sum_assignment

from roadlink.association import associate
from roadlink.association.detections import CLUTTER, Detections, FloatArray, IntArray
from roadlink.association.scores import score_grouping

try:
    from benchmarks.references import chained_groups
    from benchmarks.sumo_accuracy import EVERY_SCENARIO, LENGTH_NOISE, load_case
except ModuleNotFoundError:  # run as a script: its folder is on the path
    from references import chained_groups  # type: ignore[no-redef]
    from sumo_accuracy import (  # type: ignore[no-redef]
        EVERY_SCENARIO,
        LENGTH_NOISE,
        load_case,
    )

RESULTS = Path(__file__).parent / "results" / "lane_order.json"
SCENARIOS = ("sumo-bottleneck", "sumo-queue", "sumo-stopgo")
METHODS = ("assignment, no lane anchors", "assignment", "lane order, true curves")
CURVE_NEIGHBOURS = 7  # each side: a curve is the running median over 15 links
FASTEST = 40.0  # m/s: a travel time shorter than the gap at this speed is impossible
LENGTH_ERROR = 0.1  # of log length, between two readings (7 % per reading)
MIN_TIME_SPREAD = 0.02  # of log travel time: a curve is never trusted to better than 2 %
MIN_CURVE_LINKS = 3


@dataclass
class MethodScore:
    """A method's accuracy on one case, and its share of true links per segment."""

    accuracy: float
    segment_links: list[float]


def successors_of(groups: IntArray, sensor: IntArray) -> IntArray:
    """Each detection's next detection in its group at the next sensor (-1 = none)."""
    successor = np.full(groups.size, -1, dtype=np.int64)
    order = np.lexsort((sensor, groups))
    a, b = order[:-1], order[1:]
    linked = (groups[a] >= 0) & (groups[a] == groups[b]) & (sensor[b] == sensor[a] + 1)
    successor[a[linked]] = b[linked]
    return successor


def running_curve(passed: FloatArray, value: FloatArray, at: FloatArray) -> FloatArray:
    """The running median of `value` over the 2 x CURVE_NEIGHBOURS + 1 nearest links (by the
    time they passed the upstream sensor), read at the times `at`."""
    order = np.argsort(passed)
    passed, value = passed[order], value[order]
    median = np.array(
        [
            np.median(value[max(0, k - CURVE_NEIGHBOURS) : k + CURVE_NEIGHBOURS + 1])
            for k in range(value.size)
        ]
    )
    return np.interp(at, passed, median)


def monotone_alignment(cost: FloatArray) -> list[tuple[int, int]]:
    """The pairs (i, j) of least total cost that keep both orders (i < i' implies j < j'); any
    row or column may stay unpaired, at no cost. A cost is minus a log-likelihood ratio, so only
    pairs likelier the same vehicle than not are worth making (dynamic programming, as for the
    longest common subsequence)."""
    n, m = cost.shape
    total = np.zeros((n + 1, m + 1))
    step = np.zeros((n + 1, m + 1), dtype=np.int8)  # 0 pair, 1 skip row, 2 skip column
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            options = (
                total[i - 1, j - 1] + cost[i - 1, j - 1],
                total[i - 1, j],
                total[i, j - 1],
            )
            best = int(np.argmin(options))
            total[i, j], step[i, j] = options[best], best
    pairs = []
    i, j = n, m
    while i > 0 and j > 0:
        if step[i, j] == 0:
            pairs.append((i - 1, j - 1))
            i, j = i - 1, j - 1
        elif step[i, j] == 1:
            i -= 1
        else:
            j -= 1
    return pairs[::-1]


class Segment:
    """The detections of two neighbouring sensors, and the costs of pairing them."""

    def __init__(self, d: Detections, sensor: IntArray, k: int, gap: float) -> None:
        self.d = d
        self.up = np.flatnonzero(sensor == k)
        self.up = self.up[np.argsort(d.timestamp[self.up], kind="stable")]
        self.down = np.flatnonzero(sensor == k + 1)
        self.down = self.down[np.argsort(d.timestamp[self.down], kind="stable")]
        self.shortest = gap / FASTEST
        # Any possible travel time, evenly on a log scale: from the shortest to the longest
        # the window allows.
        span = d.timestamp.max() - d.timestamp.min()
        self.travel_range = np.log(max(span, 2 * self.shortest) / self.shortest)

    def cost(
        self, a: IntArray, b: IntArray, curve: tuple[FloatArray, FloatArray] | None
    ) -> FloatArray:
        """Minus the log-likelihood ratio "same vehicle" against "two vehicles" of pairing every
        a with every b: of the two lengths (the far one read with LENGTH_ERROR, against how
        lengths spread at the far sensor), and of the travel time against `curve` (passed
        times, log travel times) when given (against any possible travel time, evenly)."""
        d = self.d
        travel = d.timestamp[b][None, :] - d.timestamp[a][:, None]
        log_length = np.log(d.length)
        cost = -(
            log_normal(log_length[b][None, :] - log_length[a][:, None], LENGTH_ERROR)
            - np.log(self.length_density(log_length[b]))[None, :]
        )
        if curve is not None:
            passed, log_travel = curve
            expected = running_curve(passed, log_travel, d.timestamp[a])
            spread = time_spread(passed, log_travel)
            with np.errstate(divide="ignore", invalid="ignore"):
                time_error = np.log(travel) - expected[:, None]
            cost = cost - (log_normal(time_error, spread) + np.log(self.travel_range))
        return np.where((travel > self.shortest) & np.isfinite(cost), cost, np.inf)

    def length_density(self, log_length: FloatArray) -> FloatArray:
        """How densely the far sensor's log lengths lie at each value (a kernel estimate, its
        kernel the reading error)."""
        far = np.log(self.d.length[self.down])
        return np.exp(log_normal(log_length[:, None] - far[None, :], LENGTH_ERROR)).mean(axis=1)

    def link(
        self,
        lane_curve: dict[int, tuple[FloatArray, FloatArray]],
        curve: tuple[FloatArray, FloatArray] | None,
    ) -> list[tuple[int, int]]:
        """Each lane aligned in order against its curve, then the rest by one assignment."""
        d = self.d
        links: list[tuple[int, int]] = []
        for lane in np.unique(d.lane[self.up]):
            a = self.up[d.lane[self.up] == lane]
            b = self.down[d.lane[self.down] == lane]
            if a.size and b.size:
                cost = self.cost(a, b, lane_curve.get(int(lane), curve))
                links += [(a[i], b[j]) for i, j in monotone_alignment(cost)]
        linked_a = {x for x, _ in links}
        linked_b = {y for _, y in links}
        a = np.array([x for x in self.up if x not in linked_a], dtype=np.int64)
        b = np.array([y for y in self.down if y not in linked_b], dtype=np.int64)
        if a.size and b.size:
            rows, cols = likelier_pairs(self.cost(a, b, curve))
            links += list(zip(a[rows], b[cols], strict=True))
        return links


def likelier_pairs(cost: FloatArray) -> tuple[IntArray, IntArray]:
    """One-to-one pairs of least total cost, keeping only those of negative cost (likelier the
    same vehicle than not); any row or column may stay unpaired at no cost."""
    n, m = cost.shape
    padded = np.zeros((n + m, m + n))
    padded[:n, :m] = np.where(cost < 0.0, cost, 0.0)  # NaN and inf: no pair
    rows, cols = linear_sum_assignment(padded)
    real = (rows < n) & (cols < m)
    rows, cols = rows[real], cols[real]
    kept = cost[rows, cols] < 0.0
    return rows[kept], cols[kept]


def log_normal(error: FloatArray, spread: float) -> FloatArray:
    """The log density of a normal error of standard deviation `spread`."""
    return -0.5 * (error / spread) ** 2 - np.log(spread * np.sqrt(2.0 * np.pi))


def time_spread(passed: FloatArray, log_travel: FloatArray) -> float:
    """The robust spread (1.4826 x MAD) of log travel times about their running median."""
    residual = log_travel - running_curve(passed, log_travel, passed)
    return max(MIN_TIME_SPREAD, 1.4826 * float(np.median(np.abs(residual))))


def curves(
    d: Detections, a: IntArray, b: IntArray
) -> tuple[dict[int, tuple[FloatArray, FloatArray]], tuple[FloatArray, FloatArray] | None]:
    """Each lane's curve from the links a -> b that kept it, and the segment's from all."""
    log_travel = np.log(d.timestamp[b] - d.timestamp[a])
    passed = d.timestamp[a]
    by_lane = {}
    for lane in np.unique(d.lane[a]):
        kept = (d.lane[a] == lane) & (d.lane[b] == lane)
        if kept.sum() >= MIN_CURVE_LINKS:
            by_lane[int(lane)] = (passed[kept], log_travel[kept])
    whole = (passed, log_travel) if a.size >= MIN_CURVE_LINKS else None
    return by_lane, whole


def lane_order_successors(d: Detections, sensor: IntArray, truth: IntArray) -> IntArray:
    """Links by lane order against the true curves (`truth`: each detection's true successor)."""
    positions = np.unique(d.position)
    successor = np.full(len(d), -1, dtype=np.int64)
    for k in range(positions.size - 1):
        segment = Segment(d, sensor, k, positions[k + 1] - positions[k])
        a = segment.up[truth[segment.up] >= 0]
        for x, y in segment.link(*curves(d, a, truth[a])):
            successor[x] = y
    return successor


def segment_link_accuracy(successor: IntArray, truth: IntArray, sensor: IntArray) -> list[float]:
    """Per segment, the share of true links that `successor` makes."""
    shares = []
    for k in range(int(sensor.max())):
        true_link = (sensor == k) & (truth >= 0)
        shares.append(float(np.mean(successor[true_link] == truth[true_link])))
    return shares


def measure(d: Detections) -> dict[str, MethodScore]:
    """Per method: the accuracy of its grouping and its per-segment link accuracy."""
    if not (d.has_lane.all() and d.has_length.all()):
        raise SystemExit("every detection must report its lane and length (--features cases)")
    sensor = np.searchsorted(np.unique(d.position), d.position)
    labels = d.target.astype(str)
    truth_groups = np.unique(labels, return_inverse=True)[1]
    truth_groups[labels == CLUTTER] = -1
    truth = successors_of(truth_groups, sensor)
    groups = {
        "assignment, no lane anchors": np.asarray(
            associate(d, "assignment", {"lane_anchors": False}).groups
        ),
        "assignment": np.asarray(associate(d, "assignment").groups),
    }
    successors = {name: successors_of(grouping, sensor) for name, grouping in groups.items()}
    successors["lane order, true curves"] = lane_order_successors(d, sensor, truth)
    groups["lane order, true curves"] = chained_groups(successors["lane order, true curves"])
    report = {}
    for name in METHODS:
        score = score_grouping(groups[name], d.target)
        report[name] = MethodScore(
            np.nan if score is None else score.accuracy,
            segment_link_accuracy(successors[name], truth, sensor),
        )
    return report


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, default=5)
    parser.add_argument("--scenarios", nargs="+", default=list(SCENARIOS))
    parser.add_argument("--data", type=Path, help="Read the cases' CSVs from here (no SUMO).")
    parser.add_argument("--output", type=Path, default=RESULTS)
    args = parser.parse_args()
    report: dict[str, list[dict[str, MethodScore]]] = {}
    for scenario in args.scenarios:
        if scenario not in EVERY_SCENARIO:
            raise SystemExit(f"unknown scenario '{scenario}'")
        runs = [
            measure(load_case(scenario, seed, args.data, None, LENGTH_NOISE))
            for seed in range(args.seeds)
        ]
        report[scenario] = runs
        print(f"\n{scenario}, seeds 0-{args.seeds - 1} (mean)")
        for name in METHODS:
            accuracy = np.mean([run[name].accuracy for run in runs])
            links = np.mean([run[name].segment_links for run in runs], axis=0)
            cells = " ".join(f"{share:.2f}" for share in links)
            print(f"  {name:<28} accuracy {accuracy:.1%}  links per segment {cells}", flush=True)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    cases = {
        scenario: [{name: asdict(score) for name, score in run.items()} for run in runs]
        for scenario, runs in report.items()
    }
    args.output.write_text(json.dumps({"seeds": args.seeds, "cases": cases}, indent=2) + "\n")
    print(f"\nwritten to {args.output}")


if __name__ == "__main__":
    main()
