"""One raw column of detections checked: the problems found, and numbers parsed strictly.

`detections` (the `Detections` it builds) and `feature_columns` (the optional detector features)
report what is wrong with their input as `Problem`s, raised together as one `DetectionError`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt

from roadlink.association.numbers import PLAIN_DECIMAL_HINT, strictly_parsable

FloatArray = npt.NDArray[np.float64]
IntArray = npt.NDArray[np.int64]
ObjectArray = npt.NDArray[np.object_]

# Beyond this magnitude, squares and sums of timestamps or positions lose all precision in float64
# (and are certainly not real road data); rejecting them keeps every later computation finite.
MAX_ABS_VALUE = 1e12

RawColumn = Sequence[object] | npt.NDArray[Any]
"""Unvalidated input: numbers, numeric strings, or anything else to be reported as an error."""


@dataclass(frozen=True)
class Problem:
    """One thing wrong with the input: where (row, field) and what."""

    row: int | None
    field: str | None
    message: str

    def __str__(self) -> str:
        where = []
        if self.row is not None:
            where.append(f"row {self.row}")
        if self.field is not None:
            where.append(f"field '{self.field}'")
        prefix = ", ".join(where)
        return f"{prefix}: {self.message}" if prefix else self.message


class DetectionError(ValueError):
    """The detections are invalid; `problems` says where and why (rows are 1-based data rows)."""

    MAX_LISTED = 20

    def __init__(self, problems: Sequence[Problem]) -> None:
        self.problems = list(problems)
        shown = "; ".join(str(p) for p in self.problems[: self.MAX_LISTED])
        more = len(self.problems) - self.MAX_LISTED
        if more > 0:
            shown += f"; and {more} more"
        super().__init__(shown)


def float_column(name: str, values: object, problems: list[Problem]) -> FloatArray:
    """`values` as finite float64 numbers of magnitude at most MAX_ABS_VALUE; each one that is not
    is listed in `problems` (NaN in its place when it is no number at all)."""
    out = _as_floats(values)
    not_number = np.zeros(0 if out is None else out.size, dtype=bool)
    if out is None:  # some entry is not a number: find which, one by one
        raw = list(values)  # type: ignore[call-overload]
        out = np.full(len(raw), np.nan)
        not_number = np.zeros(len(raw), dtype=bool)
        for i, value in enumerate(raw):
            number = _as_floats([value])
            if number is None:
                problems.append(Problem(i + 1, name, _not_a_number(value)))
                not_number[i] = True
            else:
                out[i] = number[0]
    for row in np.flatnonzero(~np.isfinite(out) & ~not_number):
        problems.append(Problem(int(row) + 1, name, f"must be finite, got {float(out[row])}"))
    for row in np.flatnonzero(np.isfinite(out) & (np.abs(out) > MAX_ABS_VALUE)):
        problems.append(
            Problem(
                int(row) + 1,
                name,
                f"magnitude {abs(float(out[row]))!r} is beyond the limit {MAX_ABS_VALUE:g}",
            )
        )
    return out


def _not_a_number(value: object) -> str:
    """Why a value is no float: an integer too large for one (Python's ints have no limit), or
    not a number in plain decimal notation."""
    if type(value) is int:
        return f"magnitude is beyond the limit {MAX_ABS_VALUE:g}, got {len(str(abs(value)))} digits"
    shown = value.item() if isinstance(value, np.generic) else value
    return f"must be a number in {PLAIN_DECIMAL_HINT}, got {shown!r}"


def _as_floats(values: object) -> FloatArray | None:
    """The values as a flat float64 array, or None when any is not a number.

    Numbers, and text in plain decimal notation (`roadlink.association.numbers`). Booleans, None,
    bytes and text such as `30_0` or `٣٠` are not numbers, though Python and numpy would happily
    convert them.
    """
    if isinstance(values, np.ndarray):
        items = values.tolist() if values.dtype.kind in "OU" else None
    else:
        items = list(values)  # type: ignore[call-overload]
    if items is not None:
        kinds = set(map(type, items))  # at C speed: the common case is one kind
        if not kinds <= _NUMBER_TYPES:
            return None
        if str in kinds and not strictly_parsable(items if kinds == {str} else _texts(items)):
            return None
        values = items
    try:
        array = np.asarray(values)
    except ValueError:  # ragged: some entry is a sequence
        return None
    if array.ndim != 1 or array.dtype.kind not in "iufOU":
        return None
    try:
        return array.astype(np.float64)
    except (TypeError, ValueError, OverflowError):  # OverflowError: an int beyond any float
        return None


def _texts(items: list[object]) -> list[str]:
    return [v for v in items if isinstance(v, str)]


# Exact types (bool is an int to Python, not a number to roadlink); numpy's scalars included.
_NUMBER_TYPES = frozenset(
    {int, float, str, np.str_, np.float64, np.float32, np.int64, np.int32, np.int16, np.int8}
)
