"""Quick forms of numpy calls the associator makes many times on small arrays.

A paper-size batch (100 detections) makes thousands of numpy calls on arrays of ten values,
where a call's fixed cost is the work: numpy's Python-level functions (`np.full`,
`np.array_equal`, and the wrappers of array methods such as `np.flatnonzero`, `np.repeat`,
`np.searchsorted`) cost one to three microseconds more than the array methods and C calls they
come down to. The associator calls those directly where it is hot (`x.nonzero()[0]` for a 1-D
`np.flatnonzero(x)`, `x.repeat(n)` for `np.repeat(x, n)`), and these two where there is no
method: the same arrays and answers.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import numpy.typing as npt


def filled(shape: int | tuple[int, ...], value: Any, dtype: npt.DTypeLike = np.float64) -> Any:
    """np.full(shape, value, dtype): the same array."""
    array = np.empty(shape, dtype=dtype)
    array.fill(value)
    return array


def same(a: npt.NDArray[Any], b: npt.NDArray[Any]) -> bool:
    """np.array_equal(a, b) of two arrays: the same shape and the same values."""
    return a.shape == b.shape and bool(np.logical_and.reduce(a == b, axis=None))
