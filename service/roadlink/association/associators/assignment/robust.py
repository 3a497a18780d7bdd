"""Robust summaries of the many small arrays the associator measures: medians and spreads."""

from __future__ import annotations

import numpy as np
import numpy.typing as npt

from roadlink.association.detections import FloatArray

# Up to this many values, sorting a Python list beats numpy's general median machinery tenfold.
SHORT_ARRAY = 64
# The median absolute deviation times this is the standard deviation, for normal data.
MAD_TO_STD = 1.4826


def median(values: npt.ArrayLike) -> float:
    """np.median of a 1-D array, quick for short ones."""
    array = np.asarray(values, dtype=np.float64).reshape(-1)
    n = array.size
    if n == 0 or n > SHORT_ARRAY:
        return float(np.median(array))
    ordered = sorted(array.tolist())
    mid = n // 2
    return ordered[mid] if n % 2 else 0.5 * (ordered[mid - 1] + ordered[mid])


def centre_and_spread(values: FloatArray) -> tuple[float, float]:
    """Median and normal-consistent MAD."""
    centre = float(median(values))
    return centre, MAD_TO_STD * float(median(np.abs(values - centre)))
