import numpy as np
import pytest
from sklearn.metrics import adjusted_rand_score

from roadlink.association import scores
from roadlink.association.scores import adjusted_rand_index, score_grouping


def labels(*values):
    return np.array(values, dtype=object)


def groups(*values):
    return np.array(values, dtype=np.int64)


def test_perfect_grouping_under_any_group_numbering():
    m = score_grouping(groups(7, 7, 3, 3, 5), labels("A", "A", "B", "B", "C"))
    assert m is not None
    assert m.accuracy == 1.0
    assert m.pairwise_precision == m.pairwise_recall == m.pairwise_f1 == 1.0
    assert m.ari == pytest.approx(1.0)
    assert m.complete_targets == 1.0


def test_accuracy_uses_the_best_one_to_one_matching_not_majority():
    # Group 0 holds 3 of A and 2 of B; group 1 holds 2 of B. Majority voting would give both
    # groups to... A and B; the one-to-one optimum is 0->A (3) and 1->B (2): 5 of 7 right.
    m = score_grouping(groups(0, 0, 0, 0, 0, 1, 1), labels("A", "A", "A", "B", "B", "B", "B"))
    assert m.accuracy == pytest.approx(5 / 7)


def test_two_groups_cannot_both_claim_one_target():
    # Everything is target A, split across two groups: only the larger group can match A.
    m = score_grouping(groups(0, 0, 0, 1, 1), labels("A", "A", "A", "A", "A"))
    assert m.accuracy == pytest.approx(3 / 5)
    assert m.complete_targets == 0.0
    assert m.pairwise_precision == 1.0
    assert m.pairwise_recall == pytest.approx(4 / 10)  # 3 + 1 agreeing pairs of 10


def test_clutter_is_right_only_when_unassigned():
    truth = labels("A", "A", "clutter", "clutter")
    assert score_grouping(groups(0, 0, -1, -1), truth).accuracy == 1.0
    m = score_grouping(groups(0, 0, 0, -1), truth)
    assert m.accuracy == pytest.approx(3 / 4)
    assert m.pairwise_precision == pytest.approx(1 / 3)  # pairs in group 0: 3, agreeing: 1
    assert m.complete_targets == 0.0  # A's row holds a false alarm


def test_unassigned_real_detection_is_wrong():
    m = score_grouping(groups(0, -1, 1, 1), labels("A", "A", "B", "B"))
    assert m.accuracy == pytest.approx(3 / 4)
    assert m.complete_targets == pytest.approx(1 / 2)


def test_only_labelled_detections_count():
    m = score_grouping(groups(0, 0, 1, 1), labels("A", None, "B", None))
    assert m.accuracy == 1.0
    assert score_grouping(groups(0, 1), labels(None, None)) is None


def test_ari_matches_scikit_learn_with_singletons():
    rng = np.random.default_rng(3)
    truth = rng.integers(0, 6, size=60)
    pred = np.where(rng.random(60) < 0.8, truth, rng.integers(0, 6, size=60))
    m = score_grouping(pred.astype(np.int64), np.array([f"T{t}" for t in truth], dtype=object))
    assert m.ari == adjusted_rand_score(truth, pred)


@pytest.mark.parametrize("seed", range(40))
def test_the_adjusted_rand_index_is_scikit_learns_float(seed):
    """The same float as scikit-learn's, on groupings of every shape: few or many groups,
    mostly agreeing or not, one group, all singletons, a single detection."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 400))
    truth = rng.integers(0, int(rng.integers(1, n + 1)), size=n)
    shuffled = rng.integers(0, int(rng.integers(1, n + 1)), size=n)
    pred = np.where(rng.random(n) < rng.random(), truth, shuffled)
    for t, p in [(truth, pred), (truth, np.zeros(n, int)), (truth, np.arange(n)), (pred, pred)]:
        assert adjusted_rand_index(t, p) == adjusted_rand_score(t, p)


def test_large_sparse_grouping_is_scored_exactly():
    # 20,000 targets of 5 detections: a dense contingency table would need 3 GB.
    n_targets = 20_000
    truth = np.repeat(np.arange(n_targets), 5)
    pred = truth.copy()
    pred[::5] = (truth[::5] + 1) % n_targets  # every target's first detection misplaced
    m = score_grouping(pred.astype(np.int64), np.array([f"T{t}" for t in truth], dtype=object))
    assert m.accuracy == pytest.approx(4 / 5)
    assert m.complete_targets == 0.0


def test_sparse_matching_agrees_with_dense_hungarian():
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(11)
    for _ in range(200):
        n = int(rng.integers(1, 40))
        truth = rng.integers(0, int(rng.integers(1, 8)), size=n)
        pred = rng.integers(0, int(rng.integers(1, 8)), size=n)
        table = np.zeros((pred.max() + 1, truth.max() + 1), dtype=int)
        np.add.at(table, (pred, truth), 1)
        r, c = linear_sum_assignment(table, maximize=True)
        expected = table[r, c].sum() / n
        got = score_grouping(
            pred.astype(np.int64), np.array([f"T{t}" for t in truth], dtype=object)
        )
        assert got.accuracy == pytest.approx(expected)


@pytest.mark.parametrize("seed", range(5))
def test_codes_and_cells_are_numbered_as_sorting_numbered_them(seed):
    """Labels coded by hashing and cells keyed by one integer give what `np.unique` of the
    texts and of the (group, target) rows gave: the same numbers, in the same order."""
    rng = np.random.default_rng(seed)
    n = 5000
    names = np.array([f"T{k}" for k in rng.integers(0, 800, n)] + ["clutter", "é", "Z"], object)
    rng.shuffle(names)
    texts = names.astype(str)
    expected = np.where(texts == "clutter", -1, np.unique(texts, return_inverse=True)[1])
    assert np.array_equal(scores._target_codes(names), expected)
    pred = rng.integers(-1, 300, names.size)
    truth = np.maximum(expected, 0)
    pairs, counts = np.unique(np.column_stack([pred, truth]), axis=0, return_counts=True)
    got = scores._pair_counts(pred, truth)
    for column, want in zip(got, (pairs[:, 0], pairs[:, 1], counts), strict=True):
        assert np.array_equal(column, want)


@pytest.mark.parametrize("seed", range(4))
def test_the_parsers_label_column_scores_as_the_object_array(seed):
    """From the CSV parser's column (polars, null where unlabelled) the scores are the same
    floats as from the object array."""
    import polars as pl

    rng = np.random.default_rng(seed)
    n = 3000
    names = [f"T{k}" for k in rng.integers(0, 300, n)]
    names = [
        None if r < 0.1 else ("clutter" if r < 0.15 else t)
        for r, t in zip(rng.random(n), names, strict=True)
    ]
    names[:3] = ["é", "Z", "a"]
    pred = rng.integers(-1, 320, n)
    objects = np.array(names, dtype=object)
    assert score_grouping(pred, pl.Series(names, dtype=pl.String)) == score_grouping(pred, objects)
    assert score_grouping(pred, pl.Series([None] * n, dtype=pl.String)) is None


@pytest.mark.parametrize("seed", range(20))
def test_cells_alone_in_their_row_and_column_are_taken_and_the_rest_solved(seed):
    """A good grouping's table is mostly cells alone in their row and column, taken without
    the solver: the matching is one-to-one and as heavy as the dense Hungarian method's."""
    from scipy.optimize import linear_sum_assignment

    rng = np.random.default_rng(seed)
    n_targets = int(rng.integers(5, 60))
    truth = np.repeat(np.arange(n_targets), rng.integers(1, 6, n_targets))
    pred = truth.copy()
    mixed = rng.random(truth.size) < rng.uniform(0, 0.4)  # some detections in other groups
    pred[mixed] = rng.integers(0, n_targets + 5, int(mixed.sum()))
    groups, targets, counts = scores._pair_counts(pred, truth)
    matched_groups, matched_targets, matched_counts = scores._best_matching(groups, targets, counts)
    assert np.unique(matched_groups).size == matched_groups.size
    assert np.unique(matched_targets).size == matched_targets.size
    cell_count = {(int(a), int(b)): int(c) for a, b, c in zip(groups, targets, counts, strict=True)}
    assert all(
        cell_count[int(a), int(b)] == c
        for a, b, c in zip(matched_groups, matched_targets, matched_counts, strict=True)
    )
    table = np.zeros((pred.max() + 1, truth.max() + 1), dtype=int)
    np.add.at(table, (pred, truth), 1)
    r, c = linear_sum_assignment(table, maximize=True)
    assert int(matched_counts.sum()) == int(table[r, c].sum())


def _by_definition(pred, names):
    """Every figure as `score_grouping`'s docstring defines it, by brute force over a small
    grouping (the unlabelled detections dropped first)."""
    from itertools import combinations

    from scipy.optimize import linear_sum_assignment

    keep = [i for i, name in enumerate(names) if name is not None]
    pred, names = [int(pred[i]) for i in keep], [names[i] for i in keep]
    real = sorted({t for t in names if t != "clutter"})
    groups = sorted({g for g in pred if g >= 0})
    table = np.zeros((len(groups), len(real)), dtype=int)
    for g, t in zip(pred, names, strict=True):
        if g >= 0 and t != "clutter":
            table[groups.index(g), real.index(t)] += 1
    r, c = linear_sum_assignment(table, maximize=True)
    lone_clutter = sum(g < 0 and t == "clutter" for g, t in zip(pred, names, strict=True))
    pairs = list(combinations(range(len(pred)), 2))
    together = {(i, j) for i, j in pairs if pred[i] >= 0 and pred[i] == pred[j]}
    same = {(i, j) for i, j in pairs if names[i] != "clutter" and names[i] == names[j]}
    precision = len(together & same) / len(together) if together else 1.0
    recall = len(together & same) / len(same) if same else 1.0
    singles_pred = [g if g >= 0 else -1 - i for i, g in enumerate(pred)]
    singles_true = [t if t != "clutter" else f"#{i}" for i, t in enumerate(names)]
    members = {t: {i for i, n in enumerate(names) if n == t} for t in real}
    group_members = {g: {i for i, h in enumerate(pred) if h == g} for g in groups}
    whole = sum(any(members[t] == m for m in group_members.values()) for t in real)
    return {
        "accuracy": (table[r, c].sum() + lone_clutter) / len(pred),
        "pairwise_precision": precision,
        "pairwise_recall": recall,
        "ari": adjusted_rand_score(singles_true, singles_pred),
        "complete_targets": whole / len(real) if real else 1.0,
    }


@pytest.mark.parametrize("seed", range(30))
def test_every_figure_is_its_definition(seed):
    """The figures read off one contingency table and the sizes are the definitions' own, on
    groupings with unassigned, clutter and unlabelled detections, from the object array, the
    parser's column and `truth_of` alike."""
    import polars as pl

    rng = np.random.default_rng(seed)
    n = int(rng.integers(1, 70))
    names = [f"T{k}" for k in rng.integers(0, int(rng.integers(1, 12)), n)]
    names = [
        None if r < 0.1 else ("clutter" if r < 0.2 else t)
        for r, t in zip(rng.random(n), names, strict=True)
    ]
    truth = np.array([int(t[1:]) % 9 if t and t != "clutter" else -1 for t in names])
    pred = np.where(rng.random(n) < rng.random(), truth, rng.integers(-1, 9, n))
    objects = np.array(names, dtype=object)
    got = score_grouping(pred, objects)
    if all(name is None for name in names):
        assert got is None
        return
    want = _by_definition(pred, names)
    assert got is not None
    for name, value in want.items():
        assert getattr(got, name) == pytest.approx(value, abs=1e-12), name
    assert got == score_grouping(pred, pl.Series(names, dtype=pl.String))
    assert got == score_grouping(pred, scores.truth_of(objects))
