"""Every block's first chain, drawn loose, and what it teaches the chains that count.

A lane's chain (`anchors`) scores each step from one pair to the next against followers'
spread of the change of travel time, and each pair's kinematic error against a loose normal.
Neither spread nor centre is known before a chain is drawn, so each block's chain is first drawn
at a loose smoothness (`loose_chains`): the robust spread of its steps is its segment's
smoothness (`learned_smoothness`), and, where lengths pin the chains, the running median of its
pairs' kinematic errors is the centre of that block's kinematic term (`recentred`).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator
from typing import TypeVar

import numpy as np

from roadlink.association.associators.assignment.chains import (
    BAND,
    SKIP,
    STEP_TAIL,
    ChainProblem,
    smooth_chains,
)
from roadlink.association.associators.assignment.params import AssignmentParams
from roadlink.association.associators.assignment.robust import MAD_TO_STD, median
from roadlink.association.associators.assignment.sensors import Sensors
from roadlink.association.detections import FloatArray, IntArray

# From one vehicle in a lane to the next, log travel time (or its kinematic error) changes by a
# spread that each segment learns from its own chains (`learned_smoothness`): little in free
# flow, where followers keep about the same speed, and by several per cent at a queue's tail,
# where each follower waits a little longer or shorter than the one before. The first chain is
# drawn with a loose spread, which lets it run through a queue; the spread of its steps, kept
# between these bounds, draws the second.
LOOSE_SMOOTHNESS = 0.1
SMOOTHNESS_BOUNDS = (0.01, 0.15)
SMOOTHNESS_SAMPLE = 400
# A pair's kinematic error (log travel time against the gap at its mean speed) is scored as a
# normal of this spread, at most KINEMATIC_CAP (3 spreads squared) lower (`kinematic_gain`).
KINEMATIC_SPREAD = 0.5
KINEMATIC_CAP = 9.0
# A block's kinematic errors are centred on its own first chain's median from this many pairs
# on (`recentred`).
CENTRE_MIN_PAIRS = 5
CENTRE_NEIGHBOURS = 8

# Pairs of the blocks whose chains are drawn in one programme (`batches`): numpy's cost per
# call is paid once for them all, and their arrays are held at once.
BATCH_PAIRS = 1_000_000

T = TypeVar("T")
Terms = dict[int, list[tuple[FloatArray, FloatArray, FloatArray, IntArray, IntArray]]]


def learned_smoothness(
    terms: list[tuple[FloatArray, FloatArray, FloatArray]], tail: float = STEP_TAIL
) -> float:
    """A segment's spread of the change of log travel time from one follower to the next: the
    robust spread of the steps of its chains drawn at LOOSE_SMOOTHNESS (over blocks until
    SMOOTHNESS_SAMPLE steps, so a long day costs no more than a short one), within
    SMOOTHNESS_BOUNDS (LOOSE_SMOOTHNESS where they take fewer than two steps)."""
    return learned_smoothnesses({0: terms}, {0: tail})[0]


def learned_smoothnesses(
    terms: dict[int, list[tuple[FloatArray, FloatArray, FloatArray]]],
    tail: dict[int, float],
    loose: dict[tuple[int, int], list[tuple[int, int]]] | None = None,
) -> dict[int, float]:
    """Each segment's `learned_smoothness`, every segment's next block drawn in one programme
    (or taken from the blocks' chains drawn `loose` before, by segment and block)."""
    loose = loose or {}
    steps: dict[int, list[FloatArray]] = {k: [np.zeros(0)] for k in terms}
    taken = dict.fromkeys(terms, 0)
    for block in range(max((len(t) for t in terms.values()), default=0)):
        due = [k for k in terms if taken[k] < SMOOTHNESS_SAMPLE and block < len(terms[k])]
        if not due:
            break
        todo = [k for k in due if (k, block) not in loose]
        problems = [ChainProblem(*terms[k][block], LOOSE_SMOOTHNESS, tail[k]) for k in todo]
        drawn = dict(zip(todo, smooth_chains(problems), strict=True))
        for k in due:
            _, log_travel, kinematic = terms[k][block]
            pairs = drawn[k] if k in drawn else loose[(k, block)]
            steps[k].append(_step_changes(log_travel, kinematic, pairs))
            taken[k] += steps[k][-1].size
    smoothness = {}
    for k in terms:
        changes = np.concatenate(steps[k])
        smoothness[k] = (
            LOOSE_SMOOTHNESS
            if changes.size < 2
            else float(np.clip(MAD_TO_STD * median(changes), *SMOOTHNESS_BOUNDS))
        )
    return smoothness


def _step_changes(
    log_travel: FloatArray, kinematic: FloatArray, pairs: list[tuple[int, int]]
) -> FloatArray:
    """The change scored by each step of a chain (pairs within BAND of the pair before)."""
    if len(pairs) < 2:
        return np.zeros(0)
    i, j = np.array(pairs).T
    step = (np.diff(i) <= BAND) & (np.diff(j) <= BAND)
    change = np.fmin(
        np.abs(np.diff(log_travel[i, j])),
        np.abs(np.diff(kinematic[i, j])),
    )
    return change[step]


def loose_chains(
    terms: Terms,
    keys: list[tuple[int, int]],
    tail: dict[int, float],
    skips: dict[int, list[tuple[float, float]]] | None = None,
) -> dict[tuple[int, int], list[tuple[int, int]]]:
    """The chains of the blocks `keys` (segment, block) drawn at LOOSE_SMOOTHNESS, in runs,
    each skip costed as its block's chain will cost it (`skips`, by segment and block: what
    `anchors.skip_costs` says; SKIP without them): the loose chain centres the kinematic term
    the chain is drawn with, so it should slip where that chain would, no more."""
    problems = [
        (
            key,
            ChainProblem(
                *terms[key[0]][key[1]][:3],
                LOOSE_SMOOTHNESS,
                tail[key[0]],
                *(skips[key[0]][key[1]] if skips else (SKIP, SKIP)),
            ),
        )
        for key in keys
    ]
    loose: dict[tuple[int, int], list[tuple[int, int]]] = {}
    for run in batches(problems, lambda p: p[1].gain.size):
        for (key, _), pairs in zip(run, smooth_chains([p for _, p in run]), strict=True):
            loose[key] = pairs
    return loose


def recentred(
    s: Sensors,
    params: AssignmentParams,
    terms: Terms,
    loose: dict[tuple[int, int], list[tuple[int, int]]],
) -> Terms:
    """The blocks' pair terms with the kinematic error of each block that has a `loose` chain
    scored about that chain's running median (over CENTRE_NEIGHBOURS pairs either side)
    instead of about none.

    In a queue a lane's vehicles take the same time over the segment, often twice or more
    what their spot speeds say (they pass both sensors moving and stand in between): a term
    centred on none then pulls every pair of the chain towards shorter travel times, and a chain
    shifted by a vehicle or two, whose travel times are shorter by as many headways, beats the
    true one however well its lengths match (SUMO's bottleneck, the merge's lane: 14 pairs in a
    row shifted by two vehicles, their travel times 46 s against 53 s, the kinematic 22 s).
    Centred on the block's own chain, the term still keeps a chain from drifting far, and the
    lengths decide between neighbouring alignments. `anchors` draws loose chains for this only
    where lengths were measured at both sensors: without them the term is what pins a chain,
    and centred on its own chain a chain shifted by a vehicle would score as well as the true
    one (lanes alone on the SUMO scenarios: -0.4 points, stop-and-go -3.5)."""
    result = {k: list(blocks) for k, blocks in terms.items()}
    for (k, i), pairs in loose.items():
        if len(pairs) < CENTRE_MIN_PAIRS:
            continue
        gain, log_travel, kinematic, a, b = terms[k][i]
        row, column = np.array(pairs).T
        local = _running_median(kinematic[row, column], CENTRE_NEIGHBOURS)
        centre = np.interp(np.arange(a.size), row, local)[:, None]
        gain = (
            gain
            - kinematic_gain(s, params, a, b, kinematic)
            + kinematic_gain(s, params, a, b, kinematic - centre)
        )
        result[k][i] = (gain, log_travel, kinematic, a, b)
    return result


def _running_median(values: FloatArray, half: int) -> FloatArray:
    """The median of each value's window of `half` values either side (fewer at the ends)."""
    padded = np.concatenate([np.full(half, np.nan), values, np.full(half, np.nan)])
    window = np.lib.stride_tricks.sliding_window_view(padded, 2 * half + 1)
    result: FloatArray = np.nanmedian(window, axis=1)
    return result


def kinematic_gain(
    s: Sensors, params: AssignmentParams, a: IntArray, b: IntArray, kinematic: FloatArray
) -> FloatArray:
    """Each pair's log density of its kinematic error relative to none: normal, of spread
    KINEMATIC_SPREAD widened by the speed change between the two ends as the links' travel time
    is (`gating.time_residual`), and at most KINEMATIC_CAP lower. Loose, since a vehicle in a
    stop-and-go wave stops between two sensors that it passed moving; but in steady traffic it
    keeps a chain from drifting by a dozen vehicles where lengths alike cannot pin it (a crawl
    at 1.6 m/s over 200 m takes 125 s, not 50)."""
    change = s.log_speed[b][None, :] - s.log_speed[a][:, None]
    spread2 = KINEMATIC_SPREAD**2 + (params.velocity_change_ambiguity * change) ** 2
    with np.errstate(invalid="ignore"):  # NaN where a pair is impossible (its gain is -inf)
        z2 = np.nan_to_num(kinematic * kinematic / spread2, nan=0.0)
    penalty: FloatArray = -0.5 * np.fmin(z2, KINEMATIC_CAP)
    return penalty


def batches(items: list[T], size: Callable[[T], int]) -> Iterator[list[T]]:
    """`items` in order, in runs of at most BATCH_PAIRS pairs (of `size` each; an item larger
    than that alone): the chains' programme draws a run at once, and its memory grows with it."""
    run: list[T] = []
    total = 0
    for item in items:
        if run and total + size(item) > BATCH_PAIRS:
            yield run
            run, total = [], 0
        run.append(item)
        total += size(item)
    if run:
        yield run
