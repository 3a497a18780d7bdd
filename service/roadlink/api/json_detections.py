"""The fast path of a JSON batch: msgspec decodes the body into typed rows, so that the rows'
shape (known fields only, JSON numbers where numbers go, text or null where text goes) is
checked while it parses, and the columns come out of the rows without a check of their own.

It only decides, on the safe side, that the exact path (`ingest.parse_json_batch`: orjson, then
each column's types, then the problems named row by row) would read the body as it reads it:
msgspec accepts a subset of the JSON that orjson accepts and reads the same values from it
(the last of repeated keys, numbers rounded alike; tests compare both). Anything else, a body
it refuses or one whose values the core would refuse, returns None, and the exact path reads
the body again and names the problems.
"""

from __future__ import annotations

from collections import defaultdict
from itertools import count
from operator import attrgetter
from typing import Any

import msgspec
import numpy as np

from roadlink.association.feature_columns import CodedTexts

MISSING = msgspec.Raw(b"")


class Row(msgspec.Struct, forbid_unknown_fields=True, gc=False):
    """One detection of a JSON batch as the exact path's type checks accept it: `float` takes
    any JSON number (not a boolean) and `None` stands for null or an absent field."""

    position: float
    velocity: float
    timestamp: float
    sensor_id: str | None = None
    detection_id: str | None = None
    target: str | None = None
    lane: float | None = None
    length: float | None = None
    vehicle_class: str | None = None


class Body(msgspec.Struct, forbid_unknown_fields=True):
    """A JSON batch: its rows, and `associate` as its raw JSON (pydantic validates it)."""

    detections: list[Row]
    associate: msgspec.Raw = MISSING


_DECODER = msgspec.json.Decoder(Body)
NUMBER_FIELDS = ("position", "velocity", "timestamp")
TEXT_FIELDS = ("sensor_id", "detection_id", "target")
FEATURE_NUMBER_FIELDS = ("lane", "length")


def decode_rows(body: bytes) -> tuple[list[Row], bytes | None] | None:
    """The body's rows and the raw JSON of its `associate` (None when absent), or None when
    msgspec refuses the body (malformed, or not of the documented shape): the exact path then
    names what is wrong."""
    try:
        decoded = _DECODER.decode(body)
    except ValueError:  # msgspec's DecodeError and ValidationError, or bytes not UTF-8
        return None
    associate = bytes(decoded.associate)
    return decoded.detections, associate or None


def row_columns(rows: list[Row]) -> dict[str, Any]:
    """The columns of well-formed rows as `Detections.from_columns` takes them: the numbers as
    float arrays (NaN where a feature is not reported), the texts as lists of str and None, the
    vehicle classes coded (`CodedTexts`), and a feature reported by no row as None."""
    n = len(rows)
    columns: dict[str, Any] = {
        name: np.fromiter(map(attrgetter(name), rows), np.float64, n) for name in NUMBER_FIELDS
    }
    for name in TEXT_FIELDS:
        columns[name] = list(map(attrgetter(name), rows))
    for name in FEATURE_NUMBER_FIELDS:
        # None is NaN to numpy, and a JSON number never is: NaN is "not reported".
        values = np.fromiter(map(attrgetter(name), rows), np.float64, n)
        columns[name] = None if bool(np.isnan(values).all()) else values
    columns["vehicle_class"] = _coded_classes(rows)
    return columns


def _coded_classes(rows: list[Row]) -> CodedTexts | None:
    """The rows' vehicle classes as their distinct values and a code per row, numbered in order
    of first appearance (one dict lookup a row, and no list of a `str` per row: a batch has a
    handful of classes); None when no row reports one."""
    index: defaultdict[str | None, int] = defaultdict(count().__next__)
    classes = map(attrgetter("vehicle_class"), rows)
    codes = np.fromiter(map(index.__getitem__, classes), np.intp, len(rows))
    words = list(index)
    return None if words == [None] else CodedTexts(words, codes)
