"""The quick forms of numpy calls (`assignment/arrays.py`) give numpy's own answers."""

import numpy as np
import pytest

from roadlink.association.associators.assignment.arrays import filled, same


@pytest.mark.parametrize(
    ("shape", "value", "dtype"),
    [
        (5, -1, np.int64),
        ((3, 4), np.inf, np.float64),
        (0, np.nan, np.float64),
        (4, 1.0, np.float64),
    ],
)
def test_filled_is_np_full(shape: int | tuple[int, ...], value: float, dtype: type) -> None:
    quick, numpy = filled(shape, value, dtype), np.full(shape, value, dtype=dtype)
    assert quick.dtype == numpy.dtype and quick.shape == numpy.shape
    assert np.array_equal(quick, numpy, equal_nan=True)


def test_filled_defaults_to_floats() -> None:
    assert filled(3, 2).dtype == np.float64 and filled(3, 2).tolist() == [2.0, 2.0, 2.0]


@pytest.mark.parametrize(
    ("a", "b"),
    [
        ([1, 2, 3], [1, 2, 3]),
        ([1, 2, 3], [1, 2, 4]),
        ([1, 2, 3], [1, 2]),
        ([], []),
        ([[1, 2]], [1, 2]),
        ([0.0, np.nan], [0.0, np.nan]),
        ([-0.0], [0.0]),
    ],
)
def test_same_is_np_array_equal(a: list[object], b: list[object]) -> None:
    x, y = np.array(a), np.array(b)
    assert same(x, y) == np.array_equal(x, y)
