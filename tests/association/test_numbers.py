"""Strict parsing of numbers written as text."""

from __future__ import annotations

import pytest

from roadlink.association.numbers import parse_unsigned, strictly_parsable

DECIMALS = [
    "0",
    "30",
    "-1.5",
    "+2",
    ".5",
    "7.",
    "1e3",
    "1E-3",
    "-2.5e+10",
    "nan",
    "-Inf",
    "infinity",
]
NOT_DECIMALS = [
    "",
    " 30",
    "30 ",
    "30_0",
    "3_0",
    "\u0663\u0660",  # Arabic-Indic digits: float() reads 30
    "\uff13\uff10",  # full-width digits
    "\u00b2",  # superscript two: isdigit() says True
    "0x1e",
    "1,5",
    "1e",
    ".",
    "--1",
    "1\n2",
    "nanny",
]


@pytest.mark.parametrize("text", DECIMALS)
def test_plain_decimals_are_numbers(text):
    assert strictly_parsable([text, "1"])
    float(text)  # and Python agrees


@pytest.mark.parametrize("text", NOT_DECIMALS)
def test_anything_else_is_not_even_where_python_would_read_it(text):
    if strictly_parsable(["1", text, "2"]):  # then float() itself must refuse it
        with pytest.raises(ValueError):
            float(text)


def test_the_forms_float_accepts_beyond_decimal_notation_are_caught_among_many():
    cells = DECIMALS * 1000
    assert strictly_parsable(cells) and strictly_parsable([])
    for lenient in ("3_0", "\u0663\u0660", " 1", "1\t", "1\n2"):
        assert not strictly_parsable([*cells, lenient])


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("0", 0),
        ("1764000000", 1764000000),
        (b"42", 42),
        ("\u00b2", None),
        ("+1", None),
        ("-1", None),
        ("1 ", None),
        ("", None),
        ("1234567890123", None),
        (b"\xff", None),
    ],
)
def test_unsigned_integers_are_ascii_digits_only(text, expected):
    assert parse_unsigned(text, max_digits=12) == expected
