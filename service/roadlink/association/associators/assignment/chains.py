"""The order-keeping chain between two lists of detections in time order: the dynamic
programme that `anchors` runs on every lane of every segment, and its pairs' margins.

A chain pairs rows (upstream detections) with columns (downstream ones), both in time order, so
that neither order is broken. Its score is a log likelihood ratio: each pair's own gain (given),
plus, from one pair to the next, how well the change of travel time fits followers' change
(`step_score`), less a cost per detection skipped between them; or a fresh start. See
docs/assignment.md (Lane order).
"""

from __future__ import annotations

import numpy as np

from roadlink.association.detections import FloatArray, IntArray

# A step's log density is scored against that of a change drawn from anywhere within
# +-STEP_RANGE (a pair that does not follow the one before): a chain of true followers earns its
# steps, so it runs on through vehicles whose lengths alike cannot tell (cars in a queue).
STEP_RANGE = 0.5
# Followers' changes have heavy tails: where a queue forms or dissolves between two vehicles, or
# one stops in a wave that the one before crossed moving, its travel time changes by several
# spreads. A share STEP_TAIL of the changes is STEP_TAIL_WIDTH times wider than the rest, so a
# chain runs on through such a step instead of breaking (and starting afresh, free to shift by
# a vehicle). Measured on SUMO queues (bottleneck, stop-and-go, irregular spacing, faults;
# docs/assignment.md): 0.05-0.35 and widths 3-8 all helped, 0.2 and 4 most. Only where lengths
# pin the chain: with time alone, stop-and-go fell 2 points.
STEP_TAIL = 0.2
STEP_TAIL_WIDTH = 4.0
# A chain's next pair lies at most BAND rows and columns on; each detection skipped between two
# pairs (a lane changer, about one in five in a queue) costs SKIP.
BAND = 4
SKIP = 1.5
# A chain may start afresh after any earlier pair at JUMP: no tie in travel time to the pair
# before (a gap of more than BAND vehicles, or a break in the flow).
JUMP = 6.0


def smooth_chain(
    gain: FloatArray,
    log_travel: FloatArray,
    kinematic: FloatArray,
    smoothness: float,
    tail: float = STEP_TAIL,
) -> list[tuple[int, int]]:
    """The order-keeping chain of pairs (i, j) of best score (rows and columns in time order):
    each pair's `gain` (-inf: impossible), plus, from one pair to the next, the log likelihood
    ratio of the change of log travel time or of its kinematic error (the smaller), followers'
    change of spread `smoothness` (a share `tail` of it wider) against any (`step_score`), and
    minus SKIP per detection skipped between them; or a fresh start after any earlier pair at
    JUMP. Dynamic programming over the pairs, each looking back BAND rows and columns."""
    return _best_path(*_chain_scores(gain, log_travel, kinematic, smoothness, tail))


def chain_margins(
    gain: FloatArray,
    log_travel: FloatArray,
    kinematic: FloatArray,
    smoothness: float,
    tail: float = STEP_TAIL,
) -> tuple[list[tuple[int, int]], FloatArray]:
    """The best chain (`smooth_chain`) and, for each of its pairs, by how much (in log
    likelihood) it beats the best chain that gives either end another partner: a pair that a
    shifted alignment scores nearly as well as is a guess, one that every rival scores far below
    is sure. The chains through each pair are scored by running the programme forwards and
    backwards (the score of a chain does not depend on the direction it is read in)."""
    forwards, back = _chain_scores(gain, log_travel, kinematic, smoothness, tail)
    pairs = _best_path(forwards, back)
    if not pairs:
        return pairs, np.zeros(0)
    backwards = _chain_scores(
        gain[::-1, ::-1],
        log_travel[::-1, ::-1],
        kinematic[::-1, ::-1],
        smoothness,
        tail,
        trace=False,
    )[0][::-1, ::-1]
    with np.errstate(invalid="ignore"):  # -inf - -inf where a pair is impossible
        through = np.where(np.isfinite(gain), forwards + backwards - gain, -np.inf)
    i, j = np.array(pairs).T
    rows, columns = through[i], through[:, j].T
    rows[np.arange(i.size), j] = -np.inf
    columns[np.arange(j.size), i] = -np.inf
    rival = np.maximum(rows.max(axis=1), columns.max(axis=1))
    return pairs, through[i, j] - rival


def _chain_scores(
    gain: FloatArray,
    log_travel: FloatArray,
    kinematic: FloatArray,
    smoothness: float,
    tail: float = STEP_TAIL,
    trace: bool = True,
) -> tuple[FloatArray, IntArray]:
    """The best score of a chain ending at each pair (`smooth_chain`), and each pair's pair
    before in that chain (-1, -1 where it starts one; all -1 without `trace`, for a run whose
    scores alone are read). Row by row, over the columns between the row's first and last
    possible pair; within a row, every pair before it (up to BAND rows and columns back) is
    weighed at once, nearest column shift first and then nearest row, of which the first best is
    kept."""
    n, m = gain.shape
    score = np.full((n, m), -np.inf)
    back = np.full((n, m, 2), -1, dtype=np.int64)
    # Columns padded with BAND impossible ones on the left, so that every shift reads in range:
    # shift d of column j reads padded column j + BAND - d.
    padded_score = np.full((n, m + BAND), -np.inf)
    padded_travel = np.pad(log_travel, ((0, 0), (BAND, 0)), constant_values=np.nan)
    padded_kinematic = np.pad(kinematic, ((0, 0), (BAND, 0)), constant_values=np.nan)
    shifts = np.arange(1, BAND + 1)
    # best_before[j]: the best score over pairs in the rows so far and columns < j, and where.
    best_before = np.full(m + 1, -np.inf)
    where_before = np.full((m + 1, 2), -1, dtype=np.int64)
    finite = np.isfinite(gain)
    for i in range(n):
        possible = np.flatnonzero(finite[i])
        if possible.size:
            columns = np.arange(possible[0], possible[-1] + 1)
            row = np.zeros(columns.size)  # a chain may start at any pair
            jump = best_before[columns] - JUMP
            better = jump > row
            row[better] = jump[better]
            if trace:
                origin = np.full((columns.size, 2), -1, dtype=np.int64)
                origin[better] = where_before[columns][better]
            if i:
                rows = np.arange(i - 1, max(i - BAND, 0) - 1, -1)  # nearest first
                # (rows, shifts, columns) of the pairs before.
                before = (
                    rows[:, None, None],
                    BAND - shifts[None, :, None] + columns[None, None, :],
                )
                change = np.fmin(
                    np.abs(log_travel[i, columns] - padded_travel[before]),
                    np.abs(kinematic[i, columns] - padded_kinematic[before]),
                )
                step = padded_score[before] + step_score(change, smoothness, tail)
                # Rows and columns skipped between the two pairs.
                step -= SKIP * (np.arange(rows.size)[:, None, None] + shifts[None, :, None] - 1)
                step = np.where(np.isfinite(step), step, -np.inf)
                candidates = step.transpose(1, 0, 2).reshape(-1, columns.size)  # shift-major
                first_best = np.argmax(candidates, axis=0)
                best = candidates[first_best, np.arange(columns.size)]
                improved = np.flatnonzero(best > row)
                row[improved] = best[improved]
                if trace:
                    origin[improved, 0] = rows[first_best[improved] % rows.size]
                    chosen = shifts[first_best[improved] // rows.size]
                    origin[improved, 1] = columns[improved] - chosen
            score[i, columns] = row + gain[i, columns]
            if trace:
                back[i, columns] = origin
        padded_score[i, BAND:] = score[i]
        if trace:
            best_before, where_before = _best_so_far(score[i], i, best_before, where_before)
        else:
            best_before = _best_scores_so_far(score[i], best_before)
    return score, back


def step_score(change: FloatArray, smoothness: float, tail: float = STEP_TAIL) -> FloatArray:
    """The log likelihood ratio of each step's `change` of log travel time (NaN: no step):
    followers' change (a normal of spread `smoothness`, with a share `tail` of it
    STEP_TAIL_WIDTH times wider) against a change drawn evenly from +-STEP_RANGE."""
    z2 = np.square(change / smoothness)
    even = np.log(smoothness * np.sqrt(2.0 * np.pi) / (2.0 * STEP_RANGE))
    if tail <= 0:
        plain: FloatArray = -0.5 * z2 - even
        return plain
    # In place, in this order (the programme calls this for every row): log((1 - tail) N(z) +
    # tail N(z / width) / width) relative to the even density.
    core = np.multiply(z2, -0.5)
    core += np.log1p(-tail)
    wide = np.multiply(z2, 0.5, out=z2)
    wide /= STEP_TAIL_WIDTH**2
    np.subtract(np.log(tail / STEP_TAIL_WIDTH), wide, out=wide)
    with np.errstate(invalid="ignore"):  # NaN stays NaN
        np.logaddexp(core, wide, out=core)
    core -= even
    return core


def _best_path(score: FloatArray, back: IntArray) -> list[tuple[int, int]]:
    """The chain of best score, traced back from its last pair (none unless it scores > 0)."""
    if not np.isfinite(score).any() or score.max() <= 0.0:
        return []
    i, j = (int(x) for x in np.unravel_index(int(np.argmax(score)), score.shape))
    pairs = []
    while i >= 0 and j >= 0:
        pairs.append((i, j))
        i, j = (int(x) for x in back[i, j])
    return pairs[::-1]


def _best_scores_so_far(row_score: FloatArray, before: FloatArray) -> FloatArray:
    """`before` (the best score over rows < i, columns < j) updated with row i."""
    best: FloatArray = np.maximum(
        before, np.concatenate(([-np.inf], np.maximum.accumulate(row_score)))
    )
    return best


def _best_so_far(
    row_score: FloatArray, i: int, before: FloatArray, where: IntArray
) -> tuple[FloatArray, IntArray]:
    """`before` and `where` (best over rows < i, columns < j) updated with row i."""
    m = row_score.size
    running = np.maximum.accumulate(row_score)
    argmax = np.maximum.accumulate(np.where(row_score >= running, np.arange(m), 0))
    # Over columns < j: shift by one.
    candidate = np.concatenate(([-np.inf], running))
    candidate_column = np.concatenate(([-1], argmax))
    take = candidate > before
    best = np.where(take, candidate, before)
    at = np.where(take[:, None], np.stack([np.full(m + 1, i), candidate_column], axis=1), where)
    return best, at
