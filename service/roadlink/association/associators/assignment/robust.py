"""Robust summaries of the many small arrays the associator measures: medians and spreads."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roadlink.association.detections import FloatArray, IntArray

# Up to this many values, sorting a Python list beats numpy's general median machinery tenfold.
SHORT_ARRAY = 64
# The median absolute deviation times this is the standard deviation, for normal data.
MAD_TO_STD = 1.4826


def median(values: npt.ArrayLike) -> float:
    """np.median of a 1-D array, the same number, quick for short ones and long ones."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    n = array.size
    mid = n // 2
    if n > SHORT_ARRAY:
        middle = _partitioned_middle(array)
        # Which of several zeros (or NaNs) is the middle one depends on the partition: numpy's
        # own answer there, with its sign of zero.
        if middle is None or middle == 0.0:
            return float(np.median(array))
        return middle
    if n == 0:
        return float(np.median(array))
    ordered = sorted(array.tolist())
    return ordered[mid] if n % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


def _partitioned_middle(array: FloatArray) -> float | None:
    """The middle value of a long array (the mean of the two middle ones): one partition at the
    middle (numpy's vectorised one takes a single index: a sixth of np.median's time, whose
    partition takes three), then the lower half's largest. Of several zeros, whichever the
    partition puts there; None where there are NaNs."""
    n = array.size
    mid = n // 2
    part = np.partition(array, mid)
    # The ufuncs' reductions: what .any() and .max() come down to, without their wrappers.
    if np.logical_or.reduce(np.isnan(part[mid:])):
        return None
    return float(part[mid]) if n % 2 else float((np.maximum.reduce(part[:mid]) + part[mid]) / 2.0)


def centre_and_spread(values: FloatArray) -> tuple[float, float]:
    """Median and normal-consistent MAD."""
    centre = float(median(values))
    return centre, MAD_TO_STD * float(median(np.abs(values - centre)))


def spread(values: FloatArray) -> float:
    """`centre_and_spread`'s spread, the same number, without numpy's median where the middle
    value is zero (`median` asks numpy for its sign, at several times the cost): a zero's sign
    changes no absolute deviation from it. Residuals from segments' own medians (odd segments
    leave an exact zero each) often have a median of exactly zero."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    centre = _partitioned_middle(array) if array.size > SHORT_ARRAY else None
    if centre is None:
        return centre_and_spread(array)[1]
    return MAD_TO_STD * float(median(np.abs(array - centre)))


def spread_about(values: FloatArray, centre: float) -> float:
    """The normal-consistent MAD of values whose median is `centre` (`centre_and_spread`'s
    spread, when the median is known)."""
    return MAD_TO_STD * float(median(np.abs(values - centre)))


def column_medians(values: FloatArray) -> FloatArray:
    """np.median(values, axis=0) of a 2-D array, the same numbers, from one sort: numpy's
    general median costs far more on the few hundred rows the associator has."""
    n = values.shape[0]
    if n == 0 or not np.isfinite(values).all():
        return np.asarray(np.median(values, axis=0), dtype=np.float64)
    ordered = np.sort(values, axis=0)
    mid = n // 2
    if n % 2:
        return ordered[mid]
    middle: FloatArray = (ordered[mid - 1] + ordered[mid]) / 2.0
    return middle


def run_medians(values: FloatArray, sizes: IntArray) -> FloatArray | None:
    """The medians (of each column, for 2-D values) of consecutive runs of `values`' rows, run i
    `sizes[i]` rows long (at least one): `median` (or `column_medians`) of each run, the same
    numbers, from one sort of all the runs side by side, each padded with +inf (sorted last).
    None where a run is longer than SHORT_ARRAY, a value is not finite or a median is zero
    (`median` then defers to numpy, whose sign of zero may differ), for the caller to take the
    runs one by one.

    A paper-size batch has a few dozen short runs: numpy's fixed cost per call, run after run,
    was the work. Long runs are quicker one by one (a partition each, no padding)."""
    longest = int(np.maximum.reduce(sizes))  # sizes.max(), without its wrapper
    if longest > SHORT_ARRAY or not np.logical_and.reduce(np.isfinite(values), axis=None):
        return None
    n_runs = sizes.size
    row = np.arange(values.shape[0]) - (sizes.cumsum() - sizes).repeat(sizes)
    padded = np.empty((n_runs, longest, *values.shape[1:]))
    padded.fill(np.inf)
    padded[np.arange(n_runs).repeat(sizes), row] = values
    padded.sort(axis=1)
    mid = sizes // 2
    upper = padded[np.arange(n_runs), mid]
    lower = padded[np.arange(n_runs), np.maximum(mid - 1, 0)]
    odd = (sizes % 2 == 1).reshape(-1, *([1] * (values.ndim - 1)))
    middle: FloatArray = np.where(odd, upper, (lower + upper) / 2.0)
    if np.logical_or.reduce(middle == 0.0, axis=None):
        return None
    return middle


def runs(keys: IntArray, counts: IntArray) -> list[IntArray]:
    """For every key 0, 1, ...: where it occurs in `keys` (whose bincount is `counts`), in
    order; the same as np.flatnonzero(keys == k) for each k, by one stable sort."""
    # Small keys (sensor indices) sort stably by radix as 16-bit integers, several times faster.
    small = keys.size > 0 and keys.min() >= 0 and keys.max() < np.iinfo(np.int16).max
    order = np.argsort(keys.astype(np.int16) if small else keys, kind="stable")
    bounds = np.concatenate([[0], np.cumsum(counts)])
    return [order[lo:hi] for lo, hi in zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True)]
