"""assignment/chains.py: the order-keeping chain of a lane's detections at two sensors, its
margins, and its dynamic programme against the recursion it solves."""

from __future__ import annotations

import numpy as np
from scipy import stats

from roadlink.association.associators.assignment import chains
from roadlink.association.associators.assignment.chains import (
    JUMP,
    chain_margins,
    smooth_chain,
)

# A spread of the change of log travel time from one follower to the next.
SMOOTHNESS = 0.03


def chain_case(
    offset: int, n: int = 30, wait: float = 0.0
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row i is the vehicle of column i + offset; every travel time is 60 s, slowly drifting,
    and the columns are 3 s apart; each pair's gain is weakly positive for the true pair. With
    `wait`, each vehicle also waits a random time of that spread (relative to its travel time)
    as in a queue, where followers' travel times differ by a few per cent."""
    rng = np.random.default_rng(offset)
    up = np.cumsum(np.full(n, 3.0))
    passed = np.concatenate([np.arange(-offset, 0) * 3.0, up])  # earlier vehicles first
    down = passed + 60.0 + 0.01 * passed
    down[offset:] += 60.0 * wait * rng.standard_normal(n)
    down = np.maximum.accumulate(down)  # a queue keeps its order
    travel = down[None, :] - up[:, None]
    with np.errstate(invalid="ignore"):
        log_travel = np.where(travel > 0, np.log(np.maximum(travel, 1e-9)), np.nan)
    gain = rng.normal(-1.0, 1.0, travel.shape)
    gain[np.arange(n), np.arange(n) + offset] = 1.0
    gain = np.where(travel > 0, gain, -np.inf)
    return gain, log_travel, np.full_like(log_travel, np.nan)


def test_the_chain_follows_the_smooth_alignment_not_the_best_single_pairs() -> None:
    gain, log_travel, kinematic = chain_case(offset=4)
    # A pair shifted by one vehicle that fits better on its own than the true one.
    gain[10, 13] = 5.0
    pairs = smooth_chain(gain, log_travel, kinematic, SMOOTHNESS)
    assert pairs == [(i, i + 4) for i in range(30)]


def test_the_chain_keeps_order_and_makes_nothing_of_nothing() -> None:
    gain, log_travel, kinematic = chain_case(offset=2)
    pairs = smooth_chain(gain, log_travel, kinematic, SMOOTHNESS)
    rows, columns = zip(*pairs, strict=True)
    assert list(rows) == sorted(rows) and list(columns) == sorted(columns)
    assert (
        smooth_chain(np.full((4, 4), -np.inf), log_travel[:4, :4], kinematic[:4, :4], SMOOTHNESS)
        == []
    )
    # Pairs that gain nothing are not worth a chain.
    nothing = np.full((5, 5), -JUMP)
    assert smooth_chain(nothing, log_travel[:5, :5], kinematic[:5, :5], SMOOTHNESS) == []


def test_a_pair_is_as_sure_as_its_chain_beats_the_rivals_that_give_it_another_partner() -> None:
    gain, log_travel, kinematic = chain_case(offset=4)
    pairs, margins = chain_margins(gain, log_travel, kinematic, SMOOTHNESS)
    assert pairs == smooth_chain(gain, log_travel, kinematic, SMOOTHNESS)
    # A rival must skip a vehicle at each end of a shifted stretch: every pair is sure.
    assert (margins > 2.0 * 1.5).all()
    sure = dict(zip(pairs, margins, strict=True))
    # Weaker evidence for one pair (its lengths fit less well): the chain keeps it, by less.
    gain[10, 14] -= 2.0
    pairs, margins = chain_margins(gain, log_travel, kinematic, SMOOTHNESS)
    weaker = dict(zip(pairs, margins, strict=True))
    assert np.isclose(weaker[(10, 14)], sure[(10, 14)] - 2.0)
    assert np.isclose(weaker[(25, 29)], sure[(25, 29)])
    # A shifted pair that fits far better than the true one wins: no margin is left negative.
    gain[10, 15] = 20.0
    pairs, margins = chain_margins(gain, log_travel, kinematic, SMOOTHNESS)
    assert (10, 15) in pairs and (margins > 0).all()


def naive_chain_scores(
    gain: np.ndarray,
    log_travel: np.ndarray,
    kinematic: np.ndarray,
    smoothness: float,
    tail: float,
) -> np.ndarray:
    """`smooth_chain`'s recursion, pair by pair: a chain's best score ending at (i, j)."""
    n, m = gain.shape
    width = chains.STEP_TAIL_WIDTH
    follower = stats.norm(scale=smoothness)
    any_change = 1.0 / (2.0 * chains.STEP_RANGE)  # the density of a change drawn evenly

    def step_log_ratio(change: float) -> float:
        density = (1 - tail) * follower.pdf(change) + tail * follower.pdf(change / width) / width
        return float(np.log(density / any_change))

    score = np.full((n, m), -np.inf)
    for i in range(n):
        for j in range(m):
            if not np.isfinite(gain[i, j]):
                continue
            before = [score[p, q] - JUMP for p in range(i) for q in range(j)] + [0.0]
            for p in range(max(i - chains.BAND, 0), i):
                for q in range(max(j - chains.BAND, 0), j):
                    change = np.fmin(
                        abs(log_travel[i, j] - log_travel[p, q]),
                        abs(kinematic[i, j] - kinematic[p, q]),
                    )
                    if np.isnan(change):
                        continue
                    step = score[p, q] + step_log_ratio(change)
                    before.append(step - chains.SKIP * (i - p - 1 + j - q - 1))
            score[i, j] = gain[i, j] + max(b for b in before if not np.isnan(b))
    return score


def test_the_programme_scores_every_pair_as_the_recursion_says() -> None:
    # Twenty problems of different shapes, spreads and tails, drawn in one programme as
    # `anchors` draws a road's lanes: each scores as the recursion says, alone or batched.
    rng = np.random.default_rng(7)
    problems = []
    for _ in range(20):
        n, m = rng.integers(1, 10, 2)
        gain = np.where(rng.random((n, m)) < 0.3, -np.inf, rng.normal(0.0, 2.0, (n, m)))
        log_travel = rng.normal(3.0, 0.05, (n, m))
        kinematic = rng.normal(0.0, 0.1, (n, m))
        smoothness = float(rng.choice([0.01, 0.03, 0.1]))
        tail = float(rng.choice([0.0, chains.STEP_TAIL]))
        problems.append(chains.ChainProblem(gain, log_travel, kinematic, smoothness, tail))
    batched = chains._chain_scores(problems)
    for problem, (fast, _) in zip(problems, batched, strict=True):
        naive = naive_chain_scores(
            problem.gain, problem.log_travel, problem.kinematic, problem.smoothness, problem.tail
        )
        assert np.allclose(fast, naive)
        alone, _ = chains._chain_scores([problem])[0]
        assert np.array_equal(alone, fast)


def test_no_problems_draw_no_chains_and_impossible_ones_draw_empty_chains() -> None:
    assert chains.smooth_chains([]) == []
    assert chains.chains_with_margins([]) == []
    nothing = np.full((3, 4), -np.inf)
    ones = np.ones((3, 4))
    impossible = chains.ChainProblem(nothing, ones, ones, SMOOTHNESS)
    pairs, margins = chains.chains_with_margins([impossible, impossible])[1]
    assert pairs == [] and margins.size == 0
