"""The optional detector features' columns (`roadlink.association.feature_columns`): None or a
blank is "not reported", anything else must be a valid lane, length or class."""

import math

import numpy as np
import pytest

from roadlink.association.columns import Problem
from roadlink.association.detections import DetectionError, Detections
from roadlink.association.feature_columns import (
    MAX_CLASS_CHARS,
    MAX_LANE,
    MAX_LENGTH,
    NO_LANE,
    CodedTexts,
    class_column,
    classes_in_order,
    json_floats,
    lane_column,
    length_column,
)


def test_lanes_are_whole_numbers_with_blanks_unreported():
    problems: list[Problem] = []
    lanes = lane_column(5, [0, None, "2", "", MAX_LANE], problems)
    assert problems == []
    assert lanes.dtype == np.int64 and lanes.tolist() == [0, NO_LANE, 2, NO_LANE, MAX_LANE]


def test_no_lane_in_an_integer_array_means_unreported_as_detections_hold_it():
    problems: list[Problem] = []
    lanes = lane_column(3, np.array([NO_LANE, 1, NO_LANE], dtype=np.int64), problems)
    assert problems == [] and lanes.tolist() == [NO_LANE, 1, NO_LANE]


def test_lengths_keep_nan_where_unmeasured():
    problems: list[Problem] = []
    lengths = length_column(4, [4.5, "", None, MAX_LENGTH], problems)
    assert problems == []
    assert lengths[[0, 3]].tolist() == [4.5, MAX_LENGTH] and np.isnan(lengths[[1, 2]]).all()


def test_a_length_just_over_the_limit_is_shown_as_it_is_not_rounded_onto_it():
    problems: list[Problem] = []
    length_column(1, [MAX_LENGTH + 0.0001], problems)
    assert problems[0].message == "must be > 0 and at most 100, got 100.0001"


def test_problems_in_a_column_with_blanks_are_numbered_as_input_rows():
    problems: list[Problem] = []
    length_column(5, [None, "", 4.0, "x", -1.0], problems)
    assert [(p.row, p.field) for p in problems] == [(4, "length"), (5, "length")]


def test_classes_are_stripped_short_printable_words():
    problems: list[Problem] = []
    classes = class_column(4, ["car", None, " truck ", "x" * MAX_CLASS_CHARS], problems)
    assert problems == []
    assert classes.tolist() == ["car", None, "truck", "x" * MAX_CLASS_CHARS]


@pytest.mark.parametrize(
    "classes",
    [
        ["car", None, "truck", "car", None],
        [None, "5", "5", "5", "5"],
        ["car", " truck ", "car", "x" * 33, 5],  # stripped; too long and not text named
    ],
)
def test_coded_classes_read_as_the_same_classes_listed(classes):
    words = list(dict.fromkeys(classes))
    coded = CodedTexts(words, np.array([words.index(c) for c in classes]))
    listed: list[Problem] = []
    from_codes: list[Problem] = []
    expected = class_column(len(classes), classes, listed)
    assert class_column(len(classes), coded, from_codes).tolist() == expected.tolist()
    assert from_codes == listed


@pytest.mark.parametrize(
    ("words", "codes"),
    [
        (["car", None, "truck"], [0, 1, 2, 0, 1]),
        ([None, "5"], [0, 1, 1, 0]),
        (["truck", "car", None], [1, 2, 0, 1]),  # words listed out of the rows' order
        (["car", "unused", None], [0, 0, 2]),  # a word no row holds
        (["car", "truck"], [1, 1, 0]),  # every row reports one
        ([None], [0, 0]),
        (["car"], []),
    ],
)
def test_coded_classes_in_order_are_coded_as_the_listed_classes_are(words, codes):
    """`in_order` codes a parser's codes as a detection block does the listed classes: None
    first, then the words in order of first appearance."""
    coded = CodedTexts(words, np.array(codes, dtype=np.int64)).in_order()
    listed = [words[c] for c in codes]
    expected = classes_in_order(listed)
    assert coded.words == expected.words
    assert coded.words[0] is None
    assert coded.codes.tolist() == expected.codes.tolist()
    assert [coded.words[c] for c in coded.codes] == listed


@pytest.mark.parametrize(
    ("column", "bad"),
    [
        ("lane", 0.5),
        ("lane", -1),
        ("lane", 256),
        ("lane", "x"),
        ("lane", True),
        ("length", 0.0),
        ("length", -4.0),
        ("length", 1e3),
        ("length", "nan"),
        ("length", math.inf),
        ("length", math.nan),
        ("lane", math.nan),
        ("length", 10**400),
        ("vehicle_class", "x" * 33),
        ("vehicle_class", 5),
        ("vehicle_class", "car\x00x"),
    ],
)
def test_bad_features_name_row_and_field(column, bad):
    good = {"lane": 1, "length": 4.0, "vehicle_class": "car"}[column]
    with pytest.raises(DetectionError) as excinfo:
        Detections.from_columns(
            position=[0.0, 100.0, 0.0, 100.0],
            velocity=[20.0, 21.0, 30.0, 29.0],
            timestamp=[1.0, 6.0, 2.0, 5.5],
            **{column: [good, good, bad, good]},
        )
    assert [(p.row, p.field) for p in excinfo.value.problems] == [(3, column)]


@pytest.mark.parametrize(
    ("lanes", "lengths", "classes"),
    [
        ([0, None, 2, 1.0], [4.5, None, 12, 100], ["car", None, "truck", "car"]),
        ([None, None, None, 3], [None, 4.0, None, None], [None, None, None, "5"]),
        ([MAX_LANE, 0, 0, 0], [MAX_LENGTH, 1e-3, 7, 7], ["x" * MAX_CLASS_CHARS, "a", "b", "c"]),
    ],
)
def test_a_json_batchs_columns_read_as_one_value_at_a_time(lanes, lengths, classes):
    # A JSON batch's columns (numbers and None, text and None) take a path that checks whole
    # columns at once; every value must come out as the value-by-value checks make it. The
    # same values as text (a CSV's cells) take those checks.
    problems: list[Problem] = []
    as_text = [[None if v is None else str(v) for v in column] for column in (lanes, lengths)]
    assert lane_column(4, lanes, problems).tolist() == lane_column(4, as_text[0], problems).tolist()
    assert np.array_equal(
        length_column(4, lengths, problems), length_column(4, as_text[1], problems), equal_nan=True
    )
    spaced = [None if c is None else f" {c} " for c in classes]  # stripped one at a time
    assert class_column(4, classes, problems).tolist() == class_column(4, spaced, problems).tolist()
    assert problems == []


@pytest.mark.parametrize(
    "values",
    [
        [0.0, None, 2.0, 1.0],
        [None, None, None, None],
        [4.5, 1e-3, MAX_LENGTH, float(MAX_LANE)],
        [0.5, -1.0, 256.0, None],
        [math.inf, 1.0, -math.inf, None],
        [1e13, None, -1e300, 3.0],
    ],
)
def test_a_float_array_reads_as_the_same_values_listed(values):
    # A float array (NaN: not reported), as a JSON batch's number columns reach the core, is
    # checked whole when every value is within the limit; each value and each problem must be
    # what the list of the same values (None: not reported) gives, value by value.
    as_array = np.array([math.nan if v is None else v for v in values])
    for column in (lane_column, length_column):
        listed: list[Problem] = []
        arrayed: list[Problem] = []
        expected = column(4, values, listed)
        got = column(4, as_array, arrayed)
        assert np.array_equal(got, expected, equal_nan=True) and got.dtype == expected.dtype
        assert arrayed == listed


def test_json_floats_are_nan_for_null_and_none_beyond_the_limit():
    assert np.array_equal(json_floats([1, None, 2.5]), [1.0, math.nan, 2.5], equal_nan=True)
    assert json_floats([1.0, 1e13]) is None
    assert json_floats([None, -1e300]) is None
