"""The order-keeping chain between two lists of detections in time order: the dynamic
programme that `anchors` runs on every lane of every segment, and its pairs' margins.

A chain pairs rows (upstream detections) with columns (downstream ones), both in time order, so
that neither order is broken. Its score is a log likelihood ratio: each pair's own gain (given),
plus, from one pair to the next, how well the change of travel time fits followers' change
(`step_score`), less a cost per detection skipped between them; or a fresh start. Many
chains (every block of a road's lanes) are drawn in one programme, row i of each at once, since
a chain's row alone is too short to pay numpy's cost per call. See docs/assignment.md (Lane
order).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

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
# pairs (a lane changer, about one in five in a queue) costs SKIP, unless the problem says what a
# skipped row and a skipped column cost (`anchors.skip_costs`, from the lanes' learned changes).
BAND = 4
SKIP = 1.5
# A chain may start afresh after any earlier pair at JUMP: no tie in travel time to the pair
# before (a gap of more than BAND vehicles, or a break in the flow).
JUMP = 6.0


@dataclass(frozen=True)
class ChainProblem:
    """One chain to draw: each pair's gain (-inf: impossible), log travel time and kinematic
    error (rows upstream, columns downstream, both in time order), followers' spread of the
    change of log travel time, the share of it that is wider (`step_score`), and what each row
    and each column skipped between two pairs costs."""

    gain: FloatArray
    log_travel: FloatArray
    kinematic: FloatArray
    smoothness: float
    tail: float = STEP_TAIL
    skip_row: float = SKIP
    skip_column: float = SKIP

    def reversed(self) -> ChainProblem:
        """The same pairs read from the last row and column back."""
        return ChainProblem(
            self.gain[::-1, ::-1],
            self.log_travel[::-1, ::-1],
            self.kinematic[::-1, ::-1],
            self.smoothness,
            self.tail,
            self.skip_row,
            self.skip_column,
        )


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
    return smooth_chains([ChainProblem(gain, log_travel, kinematic, smoothness, tail)])[0]


def smooth_chains(problems: Sequence[ChainProblem]) -> list[list[tuple[int, int]]]:
    """Each problem's `smooth_chain`, all drawn in one programme (`_chain_scores`)."""
    return [_best_path(score, back) for score, back in _chain_scores(problems)]


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
    return chains_with_margins([ChainProblem(gain, log_travel, kinematic, smoothness, tail)])[0]


def chains_with_margins(
    problems: Sequence[ChainProblem],
) -> list[tuple[list[tuple[int, int]], FloatArray]]:
    """Each problem's `chain_margins`, all drawn in one programme forwards and one backwards."""
    forwards = _chain_scores(problems)
    backwards = _chain_scores([p.reversed() for p in problems], trace=False)
    return [
        _margins(p.gain, score, back, backward[0][::-1, ::-1])
        for p, (score, back), backward in zip(problems, forwards, backwards, strict=True)
    ]


def _margins(
    gain: FloatArray, forwards: FloatArray, back: IntArray, backwards: FloatArray
) -> tuple[list[tuple[int, int]], FloatArray]:
    """The best chain and its pairs' margins (`chain_margins`), from the scores of the chains
    ending at each pair read forwards and backwards."""
    pairs = _best_path(forwards, back)
    if not pairs:
        return pairs, np.zeros(0)
    with np.errstate(invalid="ignore"):  # -inf - -inf where a pair is impossible
        through = np.where(np.isfinite(gain), forwards + backwards - gain, -np.inf)
    i, j = np.array(pairs).T
    rows, columns = through[i], through[:, j].T
    rows[np.arange(i.size), j] = -np.inf
    columns[np.arange(j.size), i] = -np.inf
    rival = np.maximum(rows.max(axis=1), columns.max(axis=1))
    return pairs, through[i, j] - rival


@dataclass(frozen=True)
class _RowPairs:
    """The possible pairs of row i of every problem that has one: the problems (`active`), and
    for each pair its problem, the problem's place in `active`, its column, and where it lies
    in the batch's arrays."""

    active: IntArray
    owner: IntArray
    local: IntArray
    column: IntArray
    here: IntArray


@dataclass
class _Batch:
    """Many problems' arrays laid end to end, row by row, each row padded on the left with BAND
    impossible columns (so that every look back reads in range): problem p's pair (i, j) is at
    `base[p] + i * width[p] + BAND + j`. With each row's first and last possible column (-1
    where it has none), every problem's rows end to end from `row_start[p]`."""

    rows: IntArray
    columns: IntArray
    width: IntArray
    base: IntArray
    gain: FloatArray
    log_travel: FloatArray
    kinematic: FloatArray
    row_start: IntArray
    first: IntArray
    last: IntArray

    @classmethod
    def of(cls, problems: Sequence[ChainProblem]) -> _Batch:
        rows = np.array([p.gain.shape[0] for p in problems], dtype=np.int64)
        columns = np.array([p.gain.shape[1] for p in problems], dtype=np.int64)
        width = columns + BAND
        first, last = _possible_columns(problems)
        return cls(
            rows,
            columns,
            width,
            _starts(rows * width),
            _laid([p.gain for p in problems], -np.inf),
            _laid([p.log_travel for p in problems], np.nan),
            _laid([p.kinematic for p in problems], np.nan),
            _starts(rows),
            first,
            last,
        )

    def row_pairs(self, i: int) -> _RowPairs | None:
        """Row i's possible pairs, every problem's (None where no problem has one)."""
        active = np.flatnonzero(self.rows > i)
        at = self.row_start[active] + i
        active, at = active[self.first[at] >= 0], at[self.first[at] >= 0]
        if not active.size:
            return None
        count = self.last[at] - self.first[at] + 1
        owner = np.repeat(active, count)
        starts = np.repeat(np.cumsum(count) - count, count)
        column = np.repeat(self.first[at], count) + np.arange(owner.size) - starts
        here = self.base[owner] + i * self.width[owner] + BAND + column
        return _RowPairs(active, owner, np.repeat(np.arange(active.size), count), column, here)

    def scores_of(self, score: FloatArray, p: int) -> FloatArray:
        """Problem p's scores (rows, columns) out of the batch's laid-out `score`."""
        n, width = int(self.rows[p]), int(self.width[p])
        laid: FloatArray = score[self.base[p] : self.base[p] + n * width].reshape(n, width)
        return laid[:, BAND:]


def _starts(sizes: IntArray) -> IntArray:
    """Where each of consecutive runs of `sizes` starts."""
    return np.concatenate(([0], np.cumsum(sizes)[:-1])).astype(np.int64)


def _laid(arrays: list[FloatArray], fill: float) -> FloatArray:
    """The arrays' rows end to end, each padded on the left with BAND `fill`s."""
    padded = [np.pad(a, ((0, 0), (BAND, 0)), constant_values=fill) for a in arrays]
    return np.concatenate([a.ravel() for a in padded]) if padded else np.zeros(0)


def _possible_columns(problems: Sequence[ChainProblem]) -> tuple[IntArray, IntArray]:
    """Each row's first and last possible column (-1 where it has none), every problem's rows
    end to end."""
    first, last = [np.zeros(0, dtype=np.int64)], [np.zeros(0, dtype=np.int64)]
    for p in problems:
        finite = np.isfinite(p.gain)
        has = finite.any(axis=1)
        first.append(np.where(has, np.argmax(finite, axis=1), -1))
        last.append(np.where(has, p.gain.shape[1] - 1 - np.argmax(finite[:, ::-1], axis=1), -1))
    return np.concatenate(first).astype(np.int64), np.concatenate(last).astype(np.int64)


def _chain_scores(
    problems: Sequence[ChainProblem], trace: bool = True
) -> list[tuple[FloatArray, IntArray]]:
    """For each problem, the best score of a chain ending at each pair (`smooth_chain`), and
    each pair's pair before in that chain (-1, -1 where it starts one; all -1 without `trace`,
    for a run whose scores alone are read).

    Row by row, every problem's row i at once (one chain's rows depend on its rows before, but
    problems are independent, and a row is too short to pay numpy's cost per call on its own),
    over the columns between the row's first and last possible pair; within a row, every pair
    before it (up to BAND rows and columns back) is weighed at once, nearest column shift first
    and then nearest row, of which the first best is kept."""
    batch = _Batch.of(problems)
    score = np.full(batch.gain.size, -np.inf)
    back = np.full((int(np.sum(batch.rows * batch.columns)), 2), -1, dtype=np.int64)
    back_base = _starts(batch.rows * batch.columns)
    steps = _StepScores.of(problems)
    # best_before[p, j]: the best score over problem p's rows so far and columns < j, and where.
    widest = int(batch.columns.max(initial=0))
    best_before = np.full((len(problems), widest + 1), -np.inf)
    where_before = np.full((len(problems), widest + 1, 2), -1, dtype=np.int64)
    for i in range(int(batch.rows.max(initial=0))):
        pairs = batch.row_pairs(i)
        if pairs is None:
            continue
        owner, column, here = pairs.owner, pairs.column, pairs.here
        row = np.zeros(owner.size)  # a chain may start at any pair
        jump = best_before[owner, column] - JUMP
        better = jump > row
        row[better] = jump[better]
        if i:
            best, rows, shift = _best_step(batch, score, steps, pairs, i)
            improved = np.flatnonzero(best > row)
            row[improved] = best[improved]
        score[here] = row + batch.gain[here]
        row_scores = np.full((pairs.active.size, widest), -np.inf)
        row_scores[pairs.local, column] = score[here]
        active = pairs.active
        if trace:  # each pair's pair before: where it jumped from, else the step it took
            origin = np.full((owner.size, 2), -1, dtype=np.int64)
            origin[better] = where_before[owner, column][better]
            if i:
                origin[improved, 0] = rows[improved]
                origin[improved, 1] = column[improved] - shift[improved]
            back[back_base[owner] + i * batch.columns[owner] + column] = origin
            best_before[active], where_before[active] = _best_so_far(
                row_scores, i, best_before[active], where_before[active]
            )
        else:
            best_before[active] = _best_scores_so_far(row_scores, best_before[active])
    return [
        (
            batch.scores_of(score, p),
            back[back_base[p] : back_base[p] + batch.rows[p] * batch.columns[p]].reshape(
                batch.rows[p], batch.columns[p], 2
            ),
        )
        for p in range(len(problems))
    ]


def _best_step(
    batch: _Batch, score: FloatArray, steps: _StepScores, pairs: _RowPairs, i: int
) -> tuple[FloatArray, IntArray, IntArray]:
    """For each pair of row i, the best score of a chain ending at a pair before it (up to BAND
    rows and columns back, nearest column shift first and then nearest row, the first best kept)
    plus the step from that pair; and that pair's row and column shift."""
    owner, here = pairs.owner, pairs.here
    rows = np.arange(i - 1, max(i - BAND, 0) - 1, -1)  # nearest first
    shifts = np.arange(1, BAND + 1)
    # (rows, shifts, pairs) of the pairs before.
    before = (
        (here - BAND)[None, None, :]
        + ((rows - i)[:, None, None] * batch.width[owner][None, None, :])
        + (BAND - shifts)[None, :, None]
    )
    change = np.fmin(
        np.abs(batch.log_travel[here] - batch.log_travel[before]),
        np.abs(batch.kinematic[here] - batch.kinematic[before]),
    )
    step = score[before] + steps.score(change, owner)
    # Rows and columns skipped between the two pairs.
    step -= steps.skip_row[owner] * np.arange(rows.size)[:, None, None]
    step -= steps.skip_column[owner] * (shifts - 1)[None, :, None]
    step = np.where(np.isfinite(step), step, -np.inf)
    candidates = step.transpose(1, 0, 2).reshape(-1, owner.size)  # shift-major
    first_best = np.argmax(candidates, axis=0)
    best = candidates[first_best, np.arange(owner.size)]
    return best, rows[first_best % rows.size], shifts[first_best // rows.size]


@dataclass(frozen=True)
class _StepScores:
    """What `step_score` needs of each problem, as arrays to index by each pair's problem:
    scalars computed as `step_score` computes them, so that every step scores the same."""

    smoothness: FloatArray
    log_core: FloatArray  # log(1 - tail)
    log_wide: FloatArray  # log(tail / STEP_TAIL_WIDTH); -inf without a tail
    even: FloatArray
    skip_row: FloatArray
    skip_column: FloatArray

    @classmethod
    def of(cls, problems: Sequence[ChainProblem]) -> _StepScores:
        with np.errstate(divide="ignore"):  # log(0) = -inf: no wide steps
            return cls(
                np.array([p.smoothness for p in problems], dtype=np.float64),
                np.array([np.log1p(-p.tail) for p in problems], dtype=np.float64),
                np.array([np.log(p.tail / STEP_TAIL_WIDTH) for p in problems], dtype=np.float64),
                np.array([_even(p.smoothness) for p in problems], dtype=np.float64),
                np.array([p.skip_row for p in problems], dtype=np.float64),
                np.array([p.skip_column for p in problems], dtype=np.float64),
            )

    def score(self, change: FloatArray, owner: IntArray) -> FloatArray:
        """`step_score` of each step (pairs along the last axis, of problems `owner`). Without
        a tail the wide term is -inf and adds nothing: log(e^x + 0) = x, exactly."""
        z2 = np.square(change / self.smoothness[owner])
        core = np.multiply(z2, -0.5)
        core += self.log_core[owner]
        wide = np.multiply(z2, 0.5, out=z2)
        wide /= STEP_TAIL_WIDTH**2
        np.subtract(self.log_wide[owner], wide, out=wide)
        with np.errstate(invalid="ignore"):  # NaN stays NaN
            np.logaddexp(core, wide, out=core)
        core -= self.even[owner]
        return core


def _even(smoothness: float) -> float:
    """The log of followers' peak density against a change drawn evenly within +-STEP_RANGE."""
    return float(np.log(smoothness * np.sqrt(2.0 * np.pi) / (2.0 * STEP_RANGE)))


def step_score(change: FloatArray, smoothness: float, tail: float = STEP_TAIL) -> FloatArray:
    """The log likelihood ratio of each step's `change` of log travel time (NaN: no step):
    followers' change (a normal of spread `smoothness`, with a share `tail` of it
    STEP_TAIL_WIDTH times wider) against a change drawn evenly from +-STEP_RANGE."""
    z2 = np.square(change / smoothness)
    even = _even(smoothness)
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


def _best_scores_so_far(row_scores: FloatArray, before: FloatArray) -> FloatArray:
    """`before` (per problem, the best score over rows < i, columns < j) updated with each
    problem's row i (`row_scores`, one problem a row)."""
    running = np.maximum.accumulate(row_scores, axis=1)
    shifted = np.concatenate((np.full((running.shape[0], 1), -np.inf), running), axis=1)
    best: FloatArray = np.maximum(before, shifted)
    return best


def _best_so_far(
    row_scores: FloatArray, i: int, before: FloatArray, where: IntArray
) -> tuple[FloatArray, IntArray]:
    """`before` and `where` (per problem, the best over rows < i, columns < j) updated with each
    problem's row i (`row_scores`, one problem a row)."""
    count, m = row_scores.shape
    running = np.maximum.accumulate(row_scores, axis=1)
    argmax = np.maximum.accumulate(np.where(row_scores >= running, np.arange(m), 0), axis=1)
    # Over columns < j: shift by one.
    candidate = np.concatenate((np.full((count, 1), -np.inf), running), axis=1)
    candidate_column = np.concatenate((np.full((count, 1), -1), argmax), axis=1)
    take = candidate > before
    best = np.where(take, candidate, before)
    here = np.stack([np.full((count, m + 1), i), candidate_column], axis=2)
    at = np.where(take[:, :, None], here, where)
    return best, at
