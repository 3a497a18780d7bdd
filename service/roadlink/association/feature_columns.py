"""The optional detector features' columns checked: lane, length and vehicle class.

Real detectors report more than the paper's (position, velocity, timestamp), and not every sensor
measures each feature, so in these columns None or a blank means "not reported" for that
detection. `Detections.from_columns` calls these; each lists what is wrong in `problems`.
"""

from __future__ import annotations

from collections import defaultdict
from collections.abc import Sequence
from dataclasses import dataclass
from itertools import count

import numpy as np

from roadlink.association.columns import (
    MAX_ABS_VALUE,
    FloatArray,
    IntArray,
    ObjectArray,
    Problem,
    RawColumn,
    float_column,
)

NO_LANE = -1
"""The `lane` of a detection whose detector did not report one (lanes are numbered from 0)."""

# Lanes beyond this are a gateway's error, not a road (the widest motorways have a dozen or so).
MAX_LANE = 255
# A vehicle class is a short word from the deployment's own vocabulary ("car", "truck", "5").
MAX_CLASS_CHARS = 32
# No road vehicle (nor road train) is longer; a loop's length beyond it is a fault.
MAX_LENGTH = 100.0


def lane_column(n: int, given: RawColumn | None, problems: list[Problem]) -> IntArray:
    """Lanes as whole numbers from 0 to MAX_LANE; None or a blank is "not reported" (NO_LANE),
    and so is NO_LANE in an integer array (as `Detections.lane` holds them)."""
    if isinstance(given, np.ndarray) and given.dtype.kind in "iu":
        given = np.where(given == NO_LANE, np.nan, given)
    lanes = _optional_floats("lane", n, given, problems)
    reported = ~np.isnan(lanes)
    wrong = reported & ((lanes != np.round(lanes)) | (lanes < 0) | (lanes > MAX_LANE))
    for row in np.flatnonzero(wrong)[:20]:
        problems.append(
            Problem(
                int(row) + 1,
                "lane",
                f"must be a whole number from 0 to {MAX_LANE}, got {float(lanes[row]):g}",
            )
        )
    out = np.full(n, NO_LANE, dtype=np.int64)
    ok = reported & ~wrong
    out[ok] = lanes[ok].astype(np.int64)
    return out


def length_column(n: int, given: RawColumn | None, problems: list[Problem]) -> FloatArray:
    """Vehicle lengths, > 0 and at most MAX_LENGTH; None or a blank is "not measured" (NaN)."""
    lengths = _optional_floats("length", n, given, problems)
    for row in np.flatnonzero(
        (np.abs(lengths) <= MAX_ABS_VALUE) & ((lengths <= 0) | (lengths > MAX_LENGTH))
    )[:20]:
        problems.append(
            Problem(
                int(row) + 1,
                "length",
                f"must be > 0 and at most {MAX_LENGTH:g}, got {float(lengths[row])!r}",
            )
        )
    return lengths


def _optional_floats(
    name: str, n: int, given: RawColumn | None, problems: list[Problem]
) -> FloatArray:
    """A column of finite numbers in which None or a blank means "not reported" (NaN)."""
    out = np.full(n, np.nan)
    if given is None:
        return out
    plain = _plain_numbers(given)
    if plain is not None:
        return plain
    if isinstance(given, np.ndarray) and given.dtype.kind == "f":
        values: list[object] = [None if np.isnan(v) else v for v in given.tolist()]
    else:
        values = list(given)
    reported = np.flatnonzero([not _is_blank(v) for v in values])
    if reported.size:
        found: list[Problem] = []
        numbers = float_column(name, [values[i] for i in reported], found)
        # `float_column` numbered the reported values alone; renumber its rows as the input's.
        problems.extend(
            Problem(None if p.row is None else int(reported[p.row - 1]) + 1, p.field, p.message)
            for p in found
        )
        out[reported] = numbers
    return out


def _plain_numbers(given: RawColumn) -> FloatArray | None:
    """A list of JSON numbers and None (as a JSON batch gives them), or a float array with NaN
    where not reported, as floats, NaN where not reported, at C speed; None when any value is
    something else, not finite or beyond MAX_ABS_VALUE: the checks that name each problem run
    then."""
    if isinstance(given, np.ndarray):
        if given.dtype.kind != "f":
            return None
        copied = given.astype(np.float64)  # a copy: the caller's array is not shared
        return None if _beyond_limit(copied) else copied
    if not isinstance(given, list) or not set(map(type, given)) <= _JSON_NUMBER_TYPES:
        return None
    values = json_floats(given)
    if values is None or np.count_nonzero(np.isnan(values)) != given.count(None):
        return None  # a NaN given as a number
    return values


def json_floats(given: list[int | float | None]) -> FloatArray | None:
    """JSON numbers and null (types already checked, as a JSON batch's parse gives them: never
    NaN) as a float array, NaN for null; None when a value is beyond MAX_ABS_VALUE."""
    try:
        values = np.array(given, dtype=np.float64)  # None is NaN
    except OverflowError:
        return None
    return None if _beyond_limit(values) else values


def _beyond_limit(values: FloatArray) -> bool:
    """Whether a reported value (not NaN) is infinite or beyond MAX_ABS_VALUE."""
    return bool(np.any(np.abs(values) > MAX_ABS_VALUE))  # NaN compares False


_JSON_NUMBER_TYPES = {int, float, type(None)}


@dataclass(frozen=True)
class CodedTexts:
    """A text column as its distinct values (`words`, None among them where not reported) and
    each row's index among them (`codes`): how a parser hands on a column of few values (a
    batch's vehicle classes), so that each word is checked once and its `str` shared by its
    rows."""

    words: list[str | None]
    codes: IntArray

    def __len__(self) -> int:
        return len(self.codes)

    def in_order(self) -> CodedTexts:
        """The same column coded as a detection block stores it: word 0 is None (code 0, not
        reported, whether or not a row is), then the words rows hold, in order of first
        appearance (a word no row holds is dropped)."""
        n, k = len(self.codes), len(self.words)
        first = np.full(k, n, dtype=np.intp)
        np.minimum.at(first, self.codes, np.arange(n))
        held = np.flatnonzero(first < n)
        held = held[np.argsort(first[held], kind="stable")]
        words: list[str | None] = [None]
        remap = np.zeros(k, dtype=np.int64)
        for code in held.tolist():
            if self.words[code] is not None:
                remap[code] = len(words)
                words.append(self.words[code])
        return CodedTexts(words, remap[self.codes])


def classes_in_order(classes: Sequence[str | None]) -> CodedTexts:
    """Valid vehicle classes (str or None) coded as `CodedTexts.in_order` codes them: one dict
    lookup a row, numbered in order of first appearance (a batch has a handful of classes)."""
    listed = list(classes)
    index: defaultdict[str | None, int] = defaultdict(count(1).__next__, {None: 0})
    # Counted only when the first reports none (a batch with classes mostly has one there).
    if listed and not (listed[0] is None and listed.count(None) == len(listed)):
        codes = np.fromiter(map(index.__getitem__, listed), np.int64, len(listed))
    else:
        codes = np.zeros(len(listed), dtype=np.int64)
    return CodedTexts(list(index), codes)


def class_column(
    n: int, given: Sequence[str | None] | CodedTexts | None, problems: list[Problem]
) -> ObjectArray:
    """Vehicle classes: short words, None where blank."""
    return coded_class_column(n, given, problems)[0]


def coded_class_column(
    n: int, given: Sequence[str | None] | CodedTexts | None, problems: list[Problem]
) -> tuple[ObjectArray, CodedTexts | None]:
    """`class_column`, and the classes coded in order (`CodedTexts.in_order`) when they came
    coded and valid as they are: then a detection block stores those codes without coding the
    rows again."""
    if isinstance(given, CodedTexts):
        words = np.array(given.words, dtype=object)
        if _plain_classes(given.words):
            return np.asarray(words[given.codes]), given.in_order()
        # Read as a list, to name each problem.
        return class_column(n, words[given.codes].tolist(), problems), None
    out = np.full(n, None, dtype=object)
    if given is None:
        return out, None
    if _plain_classes(given):
        out[:] = given  # into the array as one list: twice np.array's speed here
        return out, None
    for i, value in enumerate(given):
        if value is not None and not isinstance(value, str):
            problems.append(Problem(i + 1, "vehicle_class", f"must be text, got {value!r}"))
            continue
        text = None if value is None else str(value).strip()
        if text and (len(text) > MAX_CLASS_CHARS or not text.isprintable()):
            problems.append(
                Problem(
                    i + 1,
                    "vehicle_class",
                    f"must be at most {MAX_CLASS_CHARS} printable characters, got {text[:40]!r}",
                )
            )
        out[i] = text or None
    return out, None


def _plain_classes(given: Sequence[str | None]) -> bool:
    """Whether the classes are text or None, each distinct one valid as it is (not blank, no
    surrounding whitespace): a batch's few classes are checked once each, not per detection."""
    if not isinstance(given, list) or not set(map(type, given)) <= {str, type(None)}:
        return False
    distinct = set(given)
    distinct.discard(None)
    return all(
        text and text == text.strip() and len(text) <= MAX_CLASS_CHARS and text.isprintable()
        for text in distinct
        if text is not None
    )


def _is_blank(value: object) -> bool:
    return value is None or (isinstance(value, str) and not value.strip())
