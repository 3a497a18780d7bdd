"""Robust summaries (`assignment/robust.py`): the quick median agrees with numpy's, and the
spread is the normal-consistent MAD."""

import numpy as np
import pytest

from roadlink.association.associators.assignment.robust import (
    MAD_TO_STD,
    SHORT_ARRAY,
    centre_and_spread,
    column_medians,
    median,
    run_medians,
    runs,
    spread,
    spread_about,
)


@pytest.mark.parametrize("n", [1, 2, 3, 10, SHORT_ARRAY, SHORT_ARRAY + 1, 1000])
def test_median_is_numpys_on_short_and_long_arrays(n: int) -> None:
    values = np.random.default_rng(n).normal(size=n)
    assert median(values) == float(np.median(values))
    assert median(values.tolist()) == float(np.median(values))


@pytest.mark.parametrize("n", [SHORT_ARRAY + 1, SHORT_ARRAY + 2, 1001, 20_000])
def test_a_long_median_is_numpys_with_ties_and_nan(n: int) -> None:
    rng = np.random.default_rng(n)
    # Few distinct values (ties at the middle), then whole numbers and exact halves.
    signed_zeros = np.where(rng.random(n) < 0.5, -0.0, 0.0) + np.where(rng.random(n) < 0.1, 1, 0)
    for values in (
        rng.integers(0, 3, n) * 0.1,
        rng.integers(-5, 5, n) / 2.0,
        np.round(rng.normal(size=n), 1),
        signed_zeros,
        rng.normal(size=n),
    ):
        assert median(values) == float(np.median(values))
        assert np.signbit(median(values)) == np.signbit(np.median(values))
    values[n // 3] = np.nan
    assert np.isnan(median(values))


def test_the_median_of_nothing_is_nan_as_numpys() -> None:
    with pytest.warns(RuntimeWarning):
        assert np.isnan(median([]))


def test_centre_and_spread_are_the_median_and_the_scaled_mad() -> None:
    assert centre_and_spread(np.array([1.0, 2.0, 3.0, 4.0, 100.0])) == (3.0, MAD_TO_STD * 1.0)
    samples = np.random.default_rng(0).normal(5.0, 2.0, size=200_000)
    centre, spread = centre_and_spread(samples)
    assert centre == pytest.approx(5.0, abs=0.02) and spread == pytest.approx(2.0, rel=0.01)


@pytest.mark.parametrize("rows", [1, 2, 3, 4, 41, 400])
def test_column_medians_are_numpys(rows: int) -> None:
    values = np.random.default_rng(rows).normal(size=(rows, 21))
    assert np.array_equal(column_medians(values), np.median(values, axis=0))
    values[0, 3] = np.nan  # numpy's answer where a value is missing
    assert np.array_equal(column_medians(values), np.median(values, axis=0), equal_nan=True)


def test_runs_are_where_each_key_occurs_in_order() -> None:
    keys = np.random.default_rng(0).integers(0, 6, size=300)
    keys[keys == 4] = 5  # a key that never occurs
    found = runs(keys, np.bincount(keys, minlength=7))
    assert len(found) == 7
    for k, where in enumerate(found):
        assert np.array_equal(where, np.flatnonzero(keys == k))
    # Keys beyond 16 bits sort as they are.
    keys = np.random.default_rng(1).integers(0, 3, size=200) * 40_000
    found = runs(keys, np.bincount(keys))
    for k, where in enumerate(found):
        assert np.array_equal(where, np.flatnonzero(keys == k))


def test_the_spread_about_the_median_is_centre_and_spreads() -> None:
    values = np.random.default_rng(1).standard_t(3, size=101)
    centre, spread = centre_and_spread(values)
    assert spread_about(values, centre) == spread


def test_the_medians_of_runs_side_by_side_are_each_runs_own() -> None:
    # To the last bit: short and long runs, odd and even, ties, one column or several.
    rng = np.random.default_rng(2)
    sizes = np.array([1, 2, 3, 10, SHORT_ARRAY - 1, SHORT_ARRAY])
    starts = np.cumsum(sizes) - sizes
    values = np.round(rng.normal(size=(sizes.sum(), 4)), 2)
    found = run_medians(values[:, 0], sizes)
    assert found is not None
    assert found.tolist() == [
        median(values[i : i + n, 0]) for i, n in zip(starts, sizes, strict=True)
    ]
    columns = run_medians(values, sizes)
    assert columns is not None
    for i, (start, n) in enumerate(zip(starts, sizes, strict=True)):
        assert np.array_equal(columns[i], column_medians(values[start : start + n]))
    # Left to the caller, run by run: a value not finite, a median of zero (its sign), a long run.
    assert run_medians(np.array([1.0, np.nan, 2.0]), np.array([1, 2])) is None
    assert run_medians(np.array([1.0, -0.0, 0.0]), np.array([1, 2])) is None
    assert run_medians(np.zeros(SHORT_ARRAY + 1) + 1.0, np.array([SHORT_ARRAY + 1])) is None


@pytest.mark.parametrize("n", [5, SHORT_ARRAY + 1, 301])
def test_the_spread_alone_is_centre_and_spreads_even_about_a_median_of_zero(n: int) -> None:
    values = np.random.default_rng(n).normal(size=n)
    values[: n // 2 + 1 : 2] = 0.0  # a median of exactly zero
    values[1 : n // 2 + 1 : 2] = -0.0
    assert spread(values) == centre_and_spread(values)[1]
    values[0] = np.nan
    assert np.isnan(spread(values)) == np.isnan(centre_and_spread(values)[1])
