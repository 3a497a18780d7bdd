"""One raw column checked (`roadlink.association.columns`): numbers parsed strictly, each problem
named by its 1-based row and field, all of them raised together."""

import math

import numpy as np
import pytest

from roadlink.association.columns import MAX_ABS_VALUE, DetectionError, Problem, float_column


def checked(values):
    problems: list[Problem] = []
    out = float_column("timestamp", values, problems)
    return out, [(p.row, p.field) for p in problems], problems


def test_numbers_and_plain_decimal_text_are_read_as_float64():
    out, rows, _ = checked([1, 2.5, "3.25", np.float32(4.0), np.int64(-5)])
    assert rows == []
    assert out.dtype == np.float64 and out.tolist() == [1.0, 2.5, 3.25, 4.0, -5.0]


@pytest.mark.parametrize("bad", [None, "fast", True, [1.0], b"1", "30_0", "٣٠"])
def test_what_python_would_convert_is_still_no_number(bad):
    out, rows, problems = checked([1.0, 2.0, bad, 4.0])
    assert rows == [(3, "timestamp")]
    assert "must be a number" in problems[0].message
    assert np.isnan(out[2]) and out[[0, 1, 3]].tolist() == [1.0, 2.0, 4.0]


@pytest.mark.parametrize("bad", [math.nan, math.inf, -math.inf, "nan", "inf"])
def test_non_finite_numbers_are_problems(bad):
    _, rows, problems = checked([1.0, bad, 2.0])
    assert rows == [(2, "timestamp")] and "must be finite" in problems[0].message


def test_magnitudes_beyond_the_limit_are_problems_and_the_limit_is_not():
    _, rows, problems = checked([MAX_ABS_VALUE, -MAX_ABS_VALUE, 3e300, -2e12])
    assert rows == [(3, "timestamp"), (4, "timestamp")]
    assert "beyond the limit" in problems[0].message


def test_a_value_just_beyond_the_limit_is_shown_as_it_is_not_rounded_onto_it():
    _, rows, problems = checked([1.0, MAX_ABS_VALUE + 0.5])
    assert rows == [(2, "timestamp")]
    assert problems[0].message == "magnitude 1000000000000.5 is beyond the limit 1e+12"


def test_an_integer_beyond_any_float_is_a_problem_not_a_crash():
    # Python's ints have no limit; numpy cannot make a float of 10**400 (OverflowError).
    _, rows, problems = checked([1.0, 10**400, -(10**400), 2])
    assert rows == [(2, "timestamp"), (3, "timestamp")]
    assert all("beyond the limit" in p.message and "401 digits" in p.message for p in problems)


def test_a_detection_error_lists_the_first_twenty_and_counts_the_rest():
    problems = [Problem(i, "lane", "bad") for i in range(1, 26)]
    error = DetectionError(problems)
    assert error.problems == problems
    assert str(error).startswith("row 1, field 'lane': bad; row 2")
    assert "row 20, field 'lane'" in str(error) and "row 21" not in str(error)
    assert str(error).endswith("; and 5 more")
    assert str(Problem(None, None, "no detections")) == "no detections"
