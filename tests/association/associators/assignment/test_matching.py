"""The generic sparse assignment solver (`assignment/matching.py`): what it takes, and that it
ends on a block that made scipy's LAPJVsp cycle."""

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from roadlink.association.associators.assignment.matching import (
    SURE_MARGIN,
    _match_dense,
    match,
    matched_cost,
    sure_matchings,
)


def test_match_takes_an_edge_only_when_it_beats_leaving_both_alone():
    left = np.array([0, 0, 1])
    right = np.array([10, 11, 10])
    cost = np.array([1.0, 5.0, 2.0])
    a, b = match(left, right, cost, gate=4.0)
    # 0-11 (5) exceeds the gate; 0-10 and 1-10 compete for 10: the cheaper one wins.
    assert dict(zip(a.tolist(), b.tolist(), strict=True)) == {0: 10}
    a, b = match(left, right, np.array([1.0, 3.0, 1.5]), gate=4.0)
    # Now 0-11 + 1-10 (4.5) beats 0-10 alone (1 + leaving 1 and 11 alone at 4).
    assert dict(zip(a.tolist(), b.tolist(), strict=True)) == {0: 11, 1: 10}


def test_edges_that_share_no_node_are_all_taken_as_the_dense_assignment_takes_them():
    left = np.array([7, 3, 5])
    right = np.array([20, 22, 21])
    cost = np.array([3.9, -1.0, 0.5])
    a, b = match(left, right, cost, gate=4.0)
    ml, mr = _match_dense(np.array([2, 0, 1]), np.array([0, 2, 1]), cost, 2.0, 3, 3)
    assert a.tolist() == [3, 5, 7] == np.array([3, 5, 7])[ml].tolist()
    assert b.tolist() == [22, 21, 20] == np.array([20, 21, 22])[mr].tolist()


def test_sparse_matching_terminates_on_a_block_that_made_lapjvsp_cycle():
    # A dense block of SUMO bottleneck traffic (174 x 186 nodes, 8003 edges) on which scipy's
    # LAPJVsp looped forever with the raw float costs. It runs in a child process so that a
    # regression fails this test instead of hanging the suite.
    data = Path(__file__).parents[3] / "data" / "lapjvsp_cycle.npz"
    script = (
        "import numpy as np, sys\n"
        "from roadlink.association.associators.assignment.matching import _match_batches\n"
        "z = np.load(sys.argv[1])\n"
        "li = np.unique(z['left'], return_inverse=True)[1]\n"
        "ri = np.unique(z['right'], return_inverse=True)[1]\n"
        "whole = np.arange(li.size), np.array([0, li.size])\n"
        "(left,), (right,) = _match_batches(li, ri, z['cost'], float(z['alone']), *whole)\n"
        "print(left.size, np.unique(left).size, np.unique(right).size)\n"
    )
    run = subprocess.run(
        [sys.executable, "-c", script, str(data)], capture_output=True, text=True, timeout=120
    )
    assert run.returncode == 0, run.stderr
    matched, distinct_left, distinct_right = map(int, run.stdout.split())
    assert matched == distinct_left == distinct_right > 100  # one-to-one, and most nodes matched


def _scipys_augmented(li, ri, cost, alone, n_l, n_r):
    """The graph of one batch as scipy builds it from its entries (an edge given twice summed)."""
    from scipy.sparse import csr_matrix

    rows = np.concatenate([li, np.arange(n_l), n_l + np.arange(n_r), n_l + ri])
    cols = np.concatenate([ri, n_r + np.arange(n_l), np.arange(n_r), n_r + li])
    weights = np.concatenate([cost, np.full(n_l + n_r, alone), np.zeros(li.size)])
    weights = np.round(weights * 1024.0) / 1024.0
    weights += 1.0 - min(0.0, float(weights.min(initial=0.0)))
    expected = csr_matrix((weights, (rows, cols)), shape=(n_l + n_r, n_r + n_l))
    expected.sum_duplicates()
    return expected


def test_each_batchs_augmented_graph_is_the_one_scipy_builds_from_its_entries():
    from roadlink.association.associators.assignment.matching import AugmentedBatches

    rng = np.random.default_rng(4)
    for n_batches, repeat in ((1, False), (4, False), (1, True), (3, True)):
        # Batch k's nodes are the ids k mod n_batches: the batches' nodes interleave.
        local_l = rng.integers(0, 30, 60 * n_batches)
        local_r = rng.integers(0, 25, local_l.size)
        batch = rng.integers(0, n_batches, local_l.size)
        _, once = np.unique(np.c_[local_l, local_r, batch], axis=0, return_index=True)
        assert once.size < local_l.size  # some edge given twice
        if not repeat:
            local_l, local_r, batch = local_l[once], local_r[once], batch[once]
        li = np.unique(local_l * n_batches + batch, return_inverse=True)[1]
        ri = np.unique(local_r * n_batches + batch, return_inverse=True)[1]
        cost = rng.normal(5.0, 4.0, li.size)
        order = np.argsort(batch, kind="stable")
        cuts = np.searchsorted(batch[order], np.arange(n_batches + 1))
        built = AugmentedBatches.of(li, ri, cost, 9.0, order, cuts)
        for k in range(n_batches):
            edges = order[cuts[k] : cuts[k + 1]]
            lefts, bl = np.unique(li[edges], return_inverse=True)
            rights, br = np.unique(ri[edges], return_inverse=True)
            expected = _scipys_augmented(bl, br, cost[edges], 9.0, lefts.size, rights.size)
            graph = built.graph(k)
            assert graph.has_canonical_format or repeat
            assert np.array_equal(built.lefts[built.left_start[k] : built.left_start[k + 1]], lefts)
            assert np.array_equal(
                built.rights[built.right_start[k] : built.right_start[k + 1]], rights
            )
            assert graph.shape == expected.shape
            for name in ("indptr", "indices", "data"):
                assert np.array_equal(getattr(graph, name), getattr(expected, name))


def test_unique_inverse_is_numpys_for_few_and_many_nodes():
    from roadlink.association.associators.assignment.matching import (
        NARROW_RANGE,
        SHORT_NODES,
        unique_inverse,
    )

    rng = np.random.default_rng(5)
    for size in (0, 1, 7, SHORT_NODES, SHORT_NODES + 1, 5000):
        # Ids in a narrow range (a table), a wide one (a sort), and at the table's limit.
        for spread in (max(1, size // 2), 1000 * size + 1, NARROW_RANGE * size):
            nodes = rng.integers(0, max(1, spread), size=size) + 10**6
            nodes[:1] = 10**6
            unique, inverse = unique_inverse(nodes)
            expected_unique, expected_inverse = np.unique(nodes, return_inverse=True)
            assert np.array_equal(unique, expected_unique)
            assert unique.dtype == expected_unique.dtype
            assert np.array_equal(inverse, expected_inverse)
            assert inverse.dtype == expected_inverse.dtype
    narrow = np.array([3, 9, 3, 5] * 20, dtype=np.int32)
    assert unique_inverse(narrow)[0].dtype == np.int32


def test_a_matching_called_sure_is_the_one_match_makes() -> None:
    # Many small matchings at once, with whole-number costs (ties among rivals) and costs a
    # hair apart: wherever `sure_matchings` says a matching surely takes the chosen edges,
    # `match` takes exactly those; the chosen edges are match's own, or a wrong guess.
    rng = np.random.default_rng(7)
    gate, checked, sure_seen = 10.0, 0, 0
    for _ in range(300):
        groups = int(rng.integers(1, 6))
        edges = [
            (int(g), int(rng.integers(0, 5)), int(rng.integers(0, 5)))
            for g in range(groups)
            for _ in range(int(rng.integers(0, 9)))
        ]
        edges = sorted(set(edges))
        if not edges:
            continue
        group, left, right = (
            np.array(column, dtype=np.int64) for column in zip(*edges, strict=True)
        )
        cost = rng.integers(0, 12, size=group.size).astype(float)
        cost += rng.choice([0.0, SURE_MARGIN / 3, 0.5], size=group.size)
        solved = [
            match(left[group == g], right[group == g], cost[group == g], gate)
            for g in range(groups)
        ]
        chosen = np.zeros(group.size, dtype=bool)
        for g, (a, b) in enumerate(solved):
            taken = set(zip(a.tolist(), b.tolist(), strict=True))
            for i in np.flatnonzero(group == g):
                chosen[i] = (int(left[i]), int(right[i])) in taken
        if rng.random() < 0.3:
            chosen ^= rng.random(group.size) < 0.2  # a wrong guess in places
        sure = sure_matchings(left, right, cost, group, chosen, gate, groups)
        for g in np.flatnonzero(sure).tolist():
            a, b = solved[g]
            here = (group == g) & chosen & (cost < gate)
            assert sorted(zip(a.tolist(), b.tolist(), strict=True)) == sorted(
                zip(left[here].tolist(), right[here].tolist(), strict=True)
            )
            sure_seen += 1
        checked += groups
    assert sure_seen > checked // 10  # not vacuous


def test_a_matching_is_not_sure_at_a_tie_or_with_a_node_left_out() -> None:
    left, right = np.array([0, 0, 1]), np.array([0, 1, 1])
    group = np.zeros(3, dtype=np.int64)
    clear = np.array([1.0, 5.0, 2.0])
    chosen = np.array([True, False, True])
    assert sure_matchings(left, right, clear, group, chosen, 10.0, 1).tolist() == [True]
    tied = np.array([1.0, 2.0, 2.0])  # left 0 to right 1 costs what right 1's own edge does
    assert sure_matchings(left, right, tied, group, chosen, 10.0, 1).tolist() == [False]
    # Left 1 left out, though it has an edge under the gate; an empty second matching is sure.
    alone = np.array([True, False, False])
    assert sure_matchings(left, right, clear, group, alone, 10.0, 2).tolist() == [False, True]


def test_sure_matchings_of_far_apart_ids_are_those_of_the_ids_renumbered() -> None:
    # Many matchings of few nodes whose ids are spread far (a long road's detections): the
    # same answers as with the ids numbered from 0, from tables as long as the edges.
    rng = np.random.default_rng(3)
    groups = 500
    group = np.repeat(np.arange(groups), 4)
    left = np.tile([0, 0, 1, 1], groups)
    right = np.tile([0, 1, 0, 1], groups)
    cost = rng.uniform(0.0, 12.0, group.size)
    chosen = np.tile([True, False, False, True], groups)
    near = sure_matchings(left, right, cost, group, chosen, 10.0, groups)
    far = sure_matchings(left + 10**6 * group, right + 7 * 10**5, cost, group, chosen, 10.0, groups)
    assert np.array_equal(near, far) and 0 < near.sum() < groups


def test_the_matched_cost_is_the_chosen_edges_and_half_a_gate_for_each_node_alone():
    left, right = np.array([0, 0, 1, 1, 2]), np.array([10, 11, 10, 11, 12])
    cost = np.array([1.0, 4.0, 3.0, 0.5, 30.0])
    # Edges 0-10 and 1-11 are taken (1.5); 2 and 12 stay alone (edge 30 > gate 20): 2 x 10.
    assert matched_cost(left, right, cost, 20.0) == pytest.approx(1.5 + 20.0)
    # The swap, made cheaper, is taken instead.
    swapped = np.array([5.0, 0.2, 0.1, 5.0, 30.0])
    assert matched_cost(left, right, swapped, 20.0) == pytest.approx(0.3 + 20.0)
    assert matched_cost(left[:0], right[:0], cost[:0], 20.0) == 0.0
