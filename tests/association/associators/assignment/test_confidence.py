"""Link confidence (`assignment/confidence.py`): the marginals of the matching, how well they are
calibrated on traffic, `min_confidence`, and how the result carries them."""

from __future__ import annotations

import csv
import io
import itertools
import json
from pathlib import Path

import numpy as np
import pytest

from roadlink.association import Detections, associate
from roadlink.association.associators.assignment.matching import chosen_marginals
from roadlink.association.csvio import read_detections_csv
from roadlink.association.result import AssociationResult, result_from_dict
from roadlink.simulation import preset, simulate

SUMO = Path(__file__).parents[3] / "data" / "sumo"
GATE = 18.0


def exact(
    left: list[int], right: list[int], cost: np.ndarray, gate: float
) -> tuple[np.ndarray, np.ndarray]:
    """Every matching enumerated, each node alone at gate / 2, weighted by exp(-cost / 2): each
    edge's marginal, and which edges the most likely matching holds."""
    nodes = len(set(left)) + len(set(right))
    total, marginal = 0.0, np.zeros(len(left))
    best: tuple[int, ...] = ()
    best_weight = -1.0
    for size in range(len(left) + 1):
        for chosen in itertools.combinations(range(len(left)), size):
            ends_l = [left[e] for e in chosen]
            ends_r = [right[e] for e in chosen]
            if len(set(ends_l)) < size or len(set(ends_r)) < size:
                continue
            weight = np.exp(-(sum(cost[e] for e in chosen) + gate / 2 * (nodes - 2 * size)) / 2)
            total += weight
            marginal[list(chosen)] += weight
            if weight > best_weight:
                best, best_weight = chosen, weight
    most_likely = np.zeros(len(left), dtype=bool)
    most_likely[list(best)] = True
    return marginal / total, most_likely


def marginals(left: list[int], right: list[int], cost: np.ndarray, gate: float) -> np.ndarray:
    """`chosen_marginals` of the most likely matching's edges (NaN elsewhere)."""
    chosen = exact(left, right, cost, gate)[1]
    return chosen_marginals(np.array(left), np.array(right), cost, chosen, gate)


def test_a_link_alone_gets_its_exact_probability() -> None:
    for cost in (0.0, 12.0, 17.0):
        odds = np.exp(-(cost - GATE) / 2)
        got = marginals([0], [1], np.array([cost]), GATE)
        assert got[0] == pytest.approx(odds / (1 + odds), rel=1e-9)


def test_two_links_against_their_swap_get_their_exact_odds() -> None:
    # Staying alone is dear here: the choice is between the pair of links and its swap, whose
    # likelihood ratio is e^2 (0.881 against 0.119).
    left, right = [0, 0, 1, 1], [10, 11, 10, 11]
    cost = np.array([2.0, 5.0, 4.0, 3.0])
    truth, chosen = exact(left, right, cost, 60.0)
    assert chosen.tolist() == [True, False, False, True]
    got = marginals(left, right, cost, 60.0)
    assert got[chosen] == pytest.approx(truth[chosen], abs=1e-9)
    assert truth[0] == pytest.approx(1 / (1 + np.exp(-2.0)), abs=1e-9)


def test_marginals_are_near_the_exact_ones_on_small_graphs() -> None:
    rng = np.random.default_rng(0)
    errors = []
    for _ in range(300):
        n_left, n_right = rng.integers(1, 4, size=2)
        edges = [(i, 10 + j) for i in range(n_left) for j in range(n_right) if rng.random() < 0.7]
        if not edges:
            continue
        left, right = [e[0] for e in edges], [e[1] for e in edges]
        cost = rng.uniform(0.0, 30.0, len(edges))
        truth, chosen = exact(left, right, cost, GATE)
        got = marginals(left, right, cost, GATE)
        assert np.all(np.isnan(got[~chosen]))
        assert np.all((got[chosen] > 0) & (got[chosen] <= 1))
        errors.append(np.max(np.abs(got[chosen] - truth[chosen]), initial=0.0))
    assert np.median(errors) < 0.01
    assert np.max(errors) < 0.3


def links_and_truth(result: AssociationResult) -> tuple[np.ndarray, np.ndarray]:
    """Each link's confidence, and whether it joins two detections of one vehicle. A copy of a
    passage, which joins its twin's target with no link of its own, is no link."""
    d, groups, links = result.detections, result.groups, result.link_confidence
    assert links is not None
    assigned = np.flatnonzero(groups >= 0)
    # Target by target in road order, a sensor's linked detection before a copy beside it.
    order = assigned[
        np.lexsort((np.isnan(links[assigned]), d.position[assigned], groups[assigned]))
    ]
    copy = (groups[order[1:]] == groups[order[:-1]]) & (
        d.position[order[1:]] == d.position[order[:-1]]
    )
    order = order[np.r_[True, ~copy]]
    same = groups[order[1:]] == groups[order[:-1]]
    before, after = order[:-1][same], order[1:][same]
    return links[after], d.target[before] == d.target[after]


def test_confidence_is_calibrated_on_faulty_traffic() -> None:
    # SUMO dense traffic with 5 % missed, 5 % false alarms, 2 % duplicates and noisy speeds and
    # times (seed 0): measured 0.799 mean confidence for 79.3 % right links; 96.3 % right at 0.9
    # or more, 41.8 % right under 0.5.
    result = associate(read_detections_csv((SUMO / "sumo-faulty.csv").read_text()), "assignment")
    confidence, right = links_and_truth(result)
    assert abs(confidence.mean() - right.mean()) < 0.05
    assert right[confidence >= 0.9].mean() > 0.95
    assert right[confidence < 0.5].mean() < 0.5


def test_every_link_has_a_confidence_and_nothing_else_does() -> None:
    d = simulate(preset("large", false_alarm_rate=0.05), seed=2).detections
    result = associate(d, "assignment")
    links = result.link_confidence
    assert links is not None
    first = np.zeros(len(d), dtype=bool)
    for members in result.target_members():
        first[members[0]] = True
    has_link = (result.groups >= 0) & ~first
    assert np.all(np.isfinite(links[has_link])) and np.all(np.isnan(links[~has_link]))
    assert np.all((links[has_link] > 0) & (links[has_link] <= 1))


def test_min_confidence_cuts_the_weak_links_and_keeps_the_pieces_as_targets() -> None:
    d = read_detections_csv((SUMO / "sumo-faulty.csv").read_text())
    every = associate(d, "assignment")
    sure = associate(d, "assignment", {"min_confidence": 0.5})
    kept, right = links_and_truth(sure)
    _, right_before = links_and_truth(every)
    assert kept.min() >= 0.5
    assert right.mean() > right_before.mean() + 0.02  # measured 81.5 -> 84.5 %
    assert np.array_equal(sure.groups < 0, every.groups < 0)  # no piece becomes a false alarm
    assert sure.n_targets > every.n_targets


def test_the_result_carries_the_confidences_in_json_and_csv() -> None:
    d = simulate(preset("medium", false_alarm_rate=0.05), seed=4).detections
    result = associate(d, "assignment")
    document = json.loads(json.dumps(result.to_dict()))
    for target in document["targets"]:
        links = [row["link_confidence"] for row in target["detections"][1:]]
        assert "link_confidence" not in target["detections"][0]
        assert target["confidence"] == pytest.approx(float(np.prod(links)))
    assert all("link_confidence" not in row for row in document["unassigned"])
    labels = dict(zip(d.detection_id.tolist(), d.target.tolist(), strict=True))
    assert result_from_dict(document, labels).to_dict() == document

    rows = list(csv.reader(io.StringIO(result.to_matrix_csv())))
    header = rows[0]
    assert header[:3] == ["target", "confidence", "S1_detection_id"]
    assert header[3:6] == ["S1_velocity", "S1_timestamp", "S1_link_confidence"]
    first = document["targets"][0]
    assert float(rows[1][1]) == pytest.approx(first["confidence"])


def test_associators_that_group_points_report_no_confidence() -> None:
    d: Detections = simulate(preset("large"), seed=1).detections
    result = associate(d, "kmeans++")
    assert result.link_confidence is None
    assert all("confidence" not in t for t in result.to_dict()["targets"])
    assert "confidence" not in result.to_matrix_csv().splitlines()[0]


def test_without_re_pairing_the_links_are_judged_all_the_same() -> None:
    d = read_detections_csv((SUMO / "sumo-faulty.csv").read_text())
    result = associate(d, "assignment", {"refine_sweeps": 0})
    confidence, right = links_and_truth(result)
    assert np.all(np.isfinite(confidence))
    assert abs(confidence.mean() - right.mean()) < 0.05


def test_marginals_depend_on_which_edges_share_a_node_not_on_the_ids() -> None:
    # Ids indexed as they are (compact) and ids far apart (ranked first): the same numbers.
    rng = np.random.default_rng(12)
    for _ in range(20):
        n = int(rng.integers(5, 60))
        left, right = rng.integers(0, 30, n), rng.integers(0, 30, n)
        pairs = np.unique(np.stack([left, right], axis=1), axis=0)
        left, right = pairs[:, 0], pairs[:, 1]
        cost = rng.uniform(0.0, 2.0 * GATE, left.size)
        chosen = np.zeros(left.size, dtype=bool)
        seen_l, seen_r = set(), set()
        for e in rng.permutation(left.size).tolist():
            if left[e] not in seen_l and right[e] not in seen_r and rng.random() < 0.6:
                chosen[e] = True
                seen_l.add(left[e])
                seen_r.add(right[e])
        compact = chosen_marginals(left, right, cost, chosen, GATE)
        spread = chosen_marginals(left * 10**6 + 7, right * 10**5 + 3, cost, chosen, GATE)
        assert np.array_equal(compact, spread, equal_nan=True)
