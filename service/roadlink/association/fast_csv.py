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
from typing import TYPE_CHECKING, Any

import numpy as np

from roadlink.association.columns import MAX_ABS_VALUE
from roadlink.association.detections import Detections
from roadlink.association.feature_columns import MAX_CLASS_CHARS, MAX_LANE, MAX_LENGTH, NO_LANE

if TYPE_CHECKING:
    import polars as pl

NUMBER_COLUMNS = ("position", "velocity", "timestamp")
TEXT_COLUMNS = ("sensor_id", "detection_id", "target")
FEATURE_COLUMNS = ("lane", "length", "vehicle_class")
_KNOWN = frozenset((*NUMBER_COLUMNS, *TEXT_COLUMNS, *FEATURE_COLUMNS))
_UTF8_BOM = b"\xef\xbb\xbf"


def fast_detections(data: bytes, max_rows: int | None = None) -> Detections | None:
    """The detections of a plain, valid CSV (see the module), or None: read it exactly then.

    With `max_rows`, a plain file of more rows returns None too (the exact reader names the
    limit), before polars reads any of it.
    """
    data = data.removeprefix(_UTF8_BOM)
    names = _plain_header(data)
    if names is None:
        return None
    lines = _plain_lines(data, len(names))
    if lines is None or lines < 2 or (max_rows is not None and lines - 1 > max_rows):
        return None
    # Imported here, on the first CSV: every process imports the core, few read CSV.
    import polars as pl

    numbers = (*NUMBER_COLUMNS, "lane", "length")
    schema = {name: (pl.Float64 if name in numbers else pl.String) for name in names}
    try:
        # Strict about width: a line with more fields than the header is an error here, so
        # with `_plain_lines`' comma count every line has exactly the header's fields.
        frame = pl.read_csv(data, has_header=False, skip_rows=1, schema=schema, quote_char=None)
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
        shared_texts(frame["target"]) if "target" in names else np.full(n, None, object),
        **features,
    )


def _plain_header(data: bytes) -> list[str] | None:
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


def _plain_lines(data: bytes, width: int) -> int | None:
    """The number of lines (the header's included), when no byte is one whose reading the exact
    reader and polars might differ on, and the file holds as many commas as lines as wide as
    the header: checked over the whole file at C speed. polars then refuses a line wider than
    the header, so that no line is narrower either (none blank: a blank line has no comma)."""
    if any(c in data for c in _NOT_PLAIN):
        return None
    newlines, commas, blanks = _count_bytes(data)
    if blanks != newlines:  # a space, a control character (Python strips \x1c-\x1f too), or
        # a byte beyond ASCII
        carriage_returns = data.count(b"\r")
        if blanks != newlines + carriage_returns or carriage_returns != data.count(b"\r\n"):
            return None  # CRLF line ends are plain; any other carriage return is not
    lines = newlines + (0 if data.endswith(b"\n") else 1)
    return lines if commas == (width - 1) * lines else None


_NOT_PLAIN = (b'"', b"'")


def _count_bytes(data: bytes) -> tuple[int, int, int]:
    """The newlines, the commas, and the bytes up to the space (controls, newlines included) or
    beyond ASCII of `data`: numpy counts a byte three times as fast as `bytes.count`; by chunks,
    so that its comparisons' memory stays small. Read as signed bytes, every byte beyond ASCII
    is negative: the one comparison counts both, so no pass of its own checks for ASCII."""
    buffer = np.frombuffer(data, dtype=np.int8)
    newlines = commas = blanks = 0
    for start in range(0, buffer.size, _CHUNK_BYTES):
        chunk = buffer[start : start + _CHUNK_BYTES]
        newlines += int(np.count_nonzero(chunk == ord("\n")))
        commas += int(np.count_nonzero(chunk == ord(",")))
        blanks += int(np.count_nonzero(chunk <= ord(" ")))
    return newlines, commas, blanks


# A chunk and its comparison stay in a core's L2 cache: 0.6 of the time of 4 MiB chunks here.
_CHUNK_BYTES = 1 << 18


def _numbers_valid(position: Any, velocity: Any, timestamp: Any) -> bool:
    """What `Detections.from_columns` checks of the numbers, at once: finite, within the
    magnitude limit, positive speeds fast enough to cross the batch's road in finite time.

    By each column's least and greatest value, without a temporary array: a NaN makes both
    NaN, which fails every comparison. The slowest speed gives the longest crossing, as
    division rounds monotonically: the same answer as dividing by every speed."""
    for values in (position, velocity, timestamp):
        low, high = float(values.min()), float(values.max())
        if not (low >= -MAX_ABS_VALUE and high <= MAX_ABS_VALUE):  # NaN and inf fail too
            return False
    slowest = float(velocity.min())
    if not slowest > 0:
        return False
    span = float(position.max() - position.min())
    with np.errstate(over="ignore"):
        return bool(np.float64(span) / np.float64(slowest) <= MAX_ABS_VALUE)


def _sensor_ids(frame: pl.DataFrame, position: Any) -> Any:
    """The sensor ids, when each names one position; generated from position rank (S1 first
    along the road) without the column; None when a cell is empty or an id has two positions."""
    if "sensor_id" not in frame.columns:
        distinct, rank = np.unique(position, return_inverse=True)
        return np.array([f"S{i + 1}" for i in range(distinct.size)], dtype=object)[rank]
    column = frame["sensor_id"]
    if column.null_count():
        return None
    import polars as pl

    spread = frame.group_by("sensor_id").agg(
        low=pl.col("position").min(), high=pl.col("position").max()
    )
    if (spread["low"] != spread["high"]).any():
        return None
    return shared_texts(column, spread["sensor_id"].to_list())


def shared_texts(column: pl.Series, names: list[str] | None = None) -> Any:
    """A text column as an object array (None where empty) holding one `str` per distinct
    value (`names`, when known), shared by its rows: a few sensor ids or labels over a million
    rows are a few objects, not a million. A column of mostly distinct values is converted as
    it is."""
    import polars as pl

    if names is None:
        names = column.unique().drop_nulls().to_list()
    if 2 * len(names) > column.len():
        return column.to_numpy().astype(object, copy=False)
    # The codes in the Enum's own integer type, an empty cell coded past the names (None).
    codes = column.cast(pl.Enum(names)).to_physical().fill_null(len(names))
    return np.array([*names, None], dtype=object)[codes.to_numpy()]


def _detection_ids_unique(frame: pl.DataFrame) -> bool:
    """Whether the detection ids (when given) are all present and distinct. Their hashes,
    sorted, are compared first (no two equal: no two ids equal); only when two hashes are equal
    are the ids themselves compared."""
    if "detection_id" not in frame.columns:
        return True
    column = frame["detection_id"]
    if column.null_count():
        return False
    hashes = np.sort(column.hash().to_numpy())  # numpy's sort: twice polars' speed here
    if not bool(np.any(hashes[1:] == hashes[:-1])):
        return True
    return column.n_unique() == frame.height


def _detection_ids(frame: pl.DataFrame) -> Any:
    """The detection ids; d1, d2, ... without the column."""
    if "detection_id" not in frame.columns:
        return np.array([f"d{i + 1}" for i in range(frame.height)], dtype=object)
    return frame["detection_id"].to_numpy().astype(object, copy=False)


def _features(frame: pl.DataFrame, n: int) -> dict[str, Any] | None:
    """The detector features the file has columns for, as the exact validators would return
    them (an absent one `Detections` fills as not reported): lane and length read by polars as
    numbers (an empty cell: not reported), checked by numpy, the classes one `str` per distinct
    value; None when a value is one the exact reader would refuse, or reads otherwise."""
    features: dict[str, Any] = {}
    for name in ("lane", "length"):
        if name not in frame.columns:
            continue
        # An empty cell is null (not reported); a "nan" is NaN, which the exact reader refuses.
        reported = ~frame[name].is_null().to_numpy()
        values = frame[name].to_numpy()
        value = values[reported]
        if name == "lane":
            valid = (value == np.round(value)) & (value >= 0) & (value <= MAX_LANE)
        else:
            valid = np.isfinite(value) & (value > 0) & (value <= MAX_LENGTH)
        if not np.all(valid):  # NaN and infinities fail every comparison they meet here
            return None
        if name == "lane":
            features[name] = np.where(reported, np.nan_to_num(values), NO_LANE).astype(np.int64)
        else:
            features[name] = np.where(reported, values, np.nan)
    if "vehicle_class" in frame.columns:
        classes = frame["vehicle_class"]
        names = classes.unique().drop_nulls().to_list()
        if any(len(name) > MAX_CLASS_CHARS for name in names):
            return None
        features["vehicle_class"] = shared_texts(classes, names)
    return features
