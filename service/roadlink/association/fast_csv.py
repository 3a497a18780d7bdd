"""The fast path of the detection CSV: polars parses, numpy checks, and only a plain, valid file
is read here; anything else (a problem to name, or a form whose meaning polars and Python's `csv`
might read differently) returns None and the exact reader (`csvio`) reads the file again.

So the result, and every error, is the exact reader's: this module only decides, cheaply and on
the safe side, that the exact reader would accept the file, and builds the same `Detections`.

A file is plain when it is ASCII, has no quote characters (`"`, nor the `'` of a spreadsheet-safe
cell), no whitespace (the exact reader strips cells; polars keeps them), no carriage return
except in CRLF line ends, and every line has as many fields as the header (no blank lines: the
exact reader skips them, polars reads a row of nulls). Its numbers are then read by polars'
float parser, which accepts a subset of what Python's `float()` accepts (plain decimal notation,
`inf`, `nan`; never `1_0`, spaces or non-ASCII digits) and rounds as correctly; non-finite
values, out-of-range ones and every other check that fails go to the exact reader.
"""

from __future__ import annotations

import csv
import mmap
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from roadlink.association.columns import MAX_ABS_VALUE
from roadlink.association.detections import Detections
from roadlink.association.feature_columns import (
    MAX_CLASS_CHARS,
    MAX_LANE,
    MAX_LENGTH,
    NO_LANE,
    CodedTexts,
)
from roadlink.association.parsed_texts import ParsedTexts, generated_ids

if TYPE_CHECKING:
    import polars as pl

NUMBER_COLUMNS = ("position", "velocity", "timestamp")
TEXT_COLUMNS = ("sensor_id", "detection_id", "target")
FEATURE_COLUMNS = ("lane", "length", "vehicle_class")
_KNOWN = frozenset((*NUMBER_COLUMNS, *TEXT_COLUMNS, *FEATURE_COLUMNS))

Buffer = bytes | mmap.mmap
"""A file's bytes, read or mapped: what `find`, slices and `np.frombuffer` take alike."""
UTF8_BOM = b"\xef\xbb\xbf"


def fast_detections(data: bytes, max_rows: int | None = None) -> Detections | None:
    """The detections of a plain, valid CSV (see the module), or None: read it exactly then.

    With `max_rows`, a plain file of more rows returns None too (the exact reader names the
    limit), before polars reads any of it.
    """
    data = data.removeprefix(UTF8_BOM)
    layout = plain_layout(data, max_rows)
    return None if layout is None else plain_detections(data, layout)


@dataclass(frozen=True)
class Layout:
    """What `plain_layout` found of a plain file: its header's names and its lines."""

    names: list[str]
    lines: int


def plain_layout(data: Buffer, max_rows: int | None = None) -> Layout | None:
    """The header and line count of a plain file (`data` without a byte-order mark: its
    bytes, or a map of them), or None when it is not plain or has more than `max_rows` rows:
    checked on its bytes, before polars reads it."""
    names = _plain_header(data)
    if names is None:
        return None
    lines = _plain_lines(data, len(names))
    if lines is None or lines < 2 or (max_rows is not None and lines - 1 > max_rows):
        return None
    return Layout(names, lines)


def plain_detections(source: bytes | Path, layout: Layout) -> Detections | None:
    """The detections of a plain file (its bytes, or its path: polars maps the file itself)
    whose `layout` was found, or None where a value is one the exact reader must name."""
    names, lines = layout.names, layout.lines
    # Imported here, on the first CSV: every process imports the core, few read CSV.
    import polars as pl

    numbers = (*NUMBER_COLUMNS, "lane", "length")
    schema = {name: (pl.Float64 if name in numbers else pl.String) for name in names}
    try:
        # Strict about width: a line with more fields than the header is an error here, so
        # with `_plain_lines`' comma count every line has exactly the header's fields.
        frame = pl.read_csv(
            source,
            has_header=False,
            skip_rows=1,
            schema=schema,
            quote_char=None,
        )
    except (pl.exceptions.PolarsError, ValueError):
        return None
    n = frame.height
    if n != lines - 1 or any(frame[name].null_count() for name in NUMBER_COLUMNS):
        return None  # an empty number: the exact reader names it
    position, velocity, timestamp = (frame[name].to_numpy() for name in NUMBER_COLUMNS)
    if not _numbers_valid(position, velocity, timestamp):
        return None
    sensors = _sensor_ids(frame, position)
    if sensors is None or not _detection_ids_unique(frame):
        return None
    features = _features(frame, n)
    if features is None:
        return None
    return Detections(
        np.ascontiguousarray(position, dtype=np.float64),
        np.ascontiguousarray(velocity, dtype=np.float64),
        np.ascontiguousarray(timestamp, dtype=np.float64),
        sensors,
        _detection_ids(frame),
        _labels(frame) if "target" in names else np.full(n, None, object),
        **features,
    )


def _plain_header(data: Buffer) -> list[str] | None:
    """The header's column names, when they are ones the exact reader accepts as they are."""
    end = data.find(b"\n")
    if end < 0:
        return None
    line = data[:end].removesuffix(b"\r")
    if not line.isascii() or line.lower() != line:
        return None
    header = next(csv.reader([line.decode("ascii")], strict=True), None)
    if header is None or any(h != h.strip() for h in header):
        return None
    if not (set(NUMBER_COLUMNS) <= set(header) <= _KNOWN) or len(set(header)) != len(header):
        return None
    return header


def _plain_lines(data: Buffer, width: int) -> int | None:
    """The number of lines (the header's included), when no byte is one whose reading the exact
    reader and polars might differ on, and the file holds as many commas as lines as wide as
    the header: checked over the whole file at C speed. polars then refuses a line wider than
    the header, so that no line is narrower either (none blank: a blank line has no comma)."""
    newlines, commas, low = _count_bytes(data)
    if low != newlines and not _plain_beside_newlines(bytes(data), newlines, low):
        return None
    lines = newlines + (0 if data[-1:] == b"\n" else 1)
    return lines if commas == (width - 1) * lines else None


def _plain_beside_newlines(data: bytes, newlines: int, low: int) -> bool:
    """Whether a file whose bytes up to the quote `'` (`low` of them, beyond ASCII included)
    are not all newlines is plain all the same: the others are the carriage returns of CRLF
    line ends, or marks of `!#$%&`, and none a quote, a space, a control character (Python
    strips \\x1c-\\x1f too), a bare carriage return or a byte beyond ASCII."""
    carriage_returns = data.count(b"\r")
    if carriage_returns != data.count(b"\r\n"):
        return False  # CRLF line ends are plain; any other carriage return is not
    if low == newlines + carriage_returns:
        return True
    if any(c in data for c in _NOT_PLAIN):
        return False
    return _count_up_to(data, ord(" ")) == newlines + carriage_returns


_NOT_PLAIN = (b'"', b"'")


def _count_bytes(data: Buffer) -> tuple[int, int, int]:
    """The newlines, the commas, and the bytes up to the quote `'` (controls, newlines, the
    space, `!"#$%&'` included) or beyond ASCII of `data`: in a plain file of LF line ends the
    last are its newlines, so that one comparison rules out quotes, blanks and bytes beyond
    ASCII at once. Read as signed bytes, every byte beyond ASCII is negative: the one
    comparison counts it too. polars counts the three at once over the file's bytes as they
    are (no copy; a bit per byte for each comparison): 0.65 of numpy's time by chunks."""
    if len(data) >= _POLARS_MAX_BYTES:  # past polars' row count: numpy, by chunks
        return _count(data, "\n"), _count(data, ","), _count_up_to(data, ord("'"))
    import polars as pl

    byte = pl.col("byte")
    frame = pl.DataFrame({"byte": np.frombuffer(data, dtype=np.int8)})
    counts = frame.lazy().select(
        (byte == ord("\n")).sum().alias("newlines"),
        (byte == ord(",")).sum().alias("commas"),
        (byte <= ord("'")).sum().alias("low"),
    )
    newlines, commas, low = counts.collect().row(0)
    return int(newlines), int(commas), int(low)


# polars' default build counts rows (and sums) in 32 bits.
_POLARS_MAX_BYTES = 1 << 32


def _count(data: Buffer, char: str) -> int:
    """The bytes of `data` equal to `char`, by chunks (see `_count_up_to`)."""
    return _chunked_count(data, lambda chunk: chunk == ord(char))


def _count_up_to(data: Buffer, highest: int) -> int:
    """The bytes of `data` up to `highest` or beyond ASCII (read as signed bytes), by chunks,
    so that the comparison's memory stays small."""
    return _chunked_count(data, lambda chunk: chunk <= highest)


def _chunked_count(data: Buffer, test: Callable[[Any], Any]) -> int:
    buffer = np.frombuffer(data, dtype=np.int8)
    return sum(
        int(np.count_nonzero(test(buffer[start : start + _CHUNK_BYTES])))
        for start in range(0, buffer.size, _CHUNK_BYTES)
    )


# A chunk and its comparison stay in a core's L2 cache.
_CHUNK_BYTES = 1 << 18


def _numbers_valid(position: Any, velocity: Any, timestamp: Any) -> bool:
    """What `Detections.from_columns` checks of the numbers, at once: finite, within the
    magnitude limit, positive speeds fast enough to cross the batch's road in finite time.

    By each column's least and greatest value, without a temporary array: a NaN makes both
    NaN, which fails every comparison. The slowest speed gives the longest crossing, as
    division rounds monotonically: the same answer as dividing by every speed."""
    bounds = [
        (float(values.min()), float(values.max())) for values in (position, velocity, timestamp)
    ]
    for low, high in bounds:
        if not (low >= -MAX_ABS_VALUE and high <= MAX_ABS_VALUE):  # NaN and inf fail too
            return False
    (nearest, farthest), (slowest, _) = bounds[0], bounds[1]
    if not slowest > 0:
        return False
    with np.errstate(over="ignore"):
        return bool(np.float64(farthest - nearest) / np.float64(slowest) <= MAX_ABS_VALUE)


def _sensor_ids(frame: pl.DataFrame, position: Any) -> Any:
    """The sensor ids, when each names one position; generated from position rank (S1 first
    along the road) without the column; None when a cell is empty or an id has two positions."""
    if "sensor_id" not in frame.columns:
        distinct, rank = np.unique(position, return_inverse=True)
        return np.array([f"S{i + 1}" for i in range(distinct.size)], dtype=object)[rank]
    column = frame["sensor_id"]
    if column.null_count():
        return None
    names, codes = text_codes(column)
    # Each id's position as its last row has it, read back at every row: all equal only when
    # each id names one position (-0.0 and 0.0 are one position, as the exact reader has it).
    at = np.empty(len(names))
    at[codes] = position
    if not np.array_equal(at[codes], position):
        return None
    return ParsedTexts(column, objects=_shared(column, names, codes))


def text_codes(column: pl.Series) -> tuple[list[str], Any]:
    """A text column's distinct values and each row's code among them (an empty cell coded
    past them): one hash pass, a Categorical of its own mapping (polars' `Categories`), where
    polars has one; else the distinct values, then an Enum of them."""
    import polars as pl

    categories = getattr(pl, "Categories", None)
    if categories is not None:
        mapping = categories.random()  # this column's own: its codes count from 0
        # The mapping lives as long as a column uses it (`mapping` is a weak reference).
        categorical = column.cast(pl.Categorical(mapping))
        names: list[Any] = list(mapping)
        if None not in names:  # a code reserved and never named (concurrent use): not here
            return names, categorical.to_physical().fill_null(len(names)).to_numpy()
    names = column.unique().drop_nulls().to_list()
    codes = column.cast(pl.Enum(names)).to_physical()  # the Enum's own integer type
    return names, codes.fill_null(len(names)).to_numpy()


def shared_texts(column: pl.Series) -> Any:
    """A text column as an object array (None where empty) holding one `str` per distinct
    value, shared by its rows: a few sensor ids or labels over a million rows are a few
    objects, not a million. A column of mostly distinct values is converted as it is."""
    return _shared(column, *text_codes(column))


def _shared(column: pl.Series, names: list[str], codes: Any) -> Any:
    if 2 * len(names) > column.len():
        return column.to_numpy().astype(object, copy=False)
    return np.array([*names, None], dtype=object)[codes]


def _detection_ids_unique(frame: pl.DataFrame) -> bool:
    """Whether the detection ids (when given) are all present and distinct. Their hashes,
    sorted, are compared first (no two equal: no two ids equal); only when two hashes are equal
    are the ids themselves compared."""
    if "detection_id" not in frame.columns:
        return True
    column = frame["detection_id"]
    if column.null_count():
        return False
    # polars 2's sort of 10^6 hashes: a third of numpy's time (19 against 62 ms, AMD EPYC).
    hashes = column.hash().sort().to_numpy()
    if not bool(np.any(hashes[1:] == hashes[:-1])):
        return True
    return column.n_unique() == frame.height


def _labels(frame: pl.DataFrame) -> ParsedTexts:
    """The labels as polars' column (null where empty): made the object array `shared_texts`
    makes only when something reads them so (the scoring reads polars' column)."""
    return ParsedTexts(frame["target"], make=shared_texts)


def _detection_ids(frame: pl.DataFrame) -> ParsedTexts:
    """The detection ids (d1, d2, ... without the column), as polars' column: `Detections`
    makes them Python strs only when something reads them so (`parsed_texts`)."""
    if "detection_id" not in frame.columns:
        return generated_ids(frame.height)
    return ParsedTexts(frame["detection_id"])


def _features(frame: pl.DataFrame, n: int) -> dict[str, Any] | None:
    """The detector features the file has columns for, as the exact validators would return
    them (an absent one `Detections` fills as not reported), with the classes coded as a
    detection block stores them (`coded_classes`); None when a value is one the exact reader
    would refuse, or reads otherwise."""
    features: dict[str, Any] = {}
    for name in ("lane", "length"):
        if name not in frame.columns:
            continue
        values = _reported_numbers(frame[name], name == "lane")
        if values is None:
            return None
        features[name] = values
    if "vehicle_class" in frame.columns:
        names, codes = text_codes(frame["vehicle_class"])  # an empty cell coded len(names)
        if any(len(name) > MAX_CLASS_CHARS for name in names):
            return None
        coded = CodedTexts([*names, None], codes).in_order()
        features["vehicle_class"] = np.array(coded.words, dtype=object)[coded.codes]
        features["coded_classes"] = coded
    return features


def _reported_numbers(column: pl.Series, lanes: bool) -> Any:
    """A lane or length column read by polars as numbers (an empty cell null: not reported) as
    `Detections` holds it, checked whole by its least and greatest value (NaN, where a cell is
    empty, ignored); None when a value is one the exact reader refuses: a "nan" (counted
    apart from the empty cells), an infinity or a value out of range (either fails a bound), a
    lane that is not a whole number."""
    values = column.to_numpy()  # NaN where a cell is empty
    empty = column.null_count()
    if empty == len(values):
        return np.full(empty, NO_LANE, dtype=np.int64) if lanes else values
    if np.count_nonzero(np.isnan(values)) != empty:
        return None
    low, high = float(np.fmin.reduce(values)), float(np.fmax.reduce(values))
    if not lanes:
        return values if low > 0 and high <= MAX_LENGTH else None
    # A NaN is the one value unequal to itself rounded: a whole lane's only unequal ones.
    whole = np.count_nonzero(np.round(values) != values) == empty
    if not (whole and low >= 0 and high <= MAX_LANE):
        return None
    return (np.nan_to_num(values, nan=NO_LANE) if empty else values).astype(np.int64)
