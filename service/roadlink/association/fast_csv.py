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

from roadlink.association.columns import MAX_ABS_VALUE, Problem
from roadlink.association.detections import Detections
from roadlink.association.feature_columns import class_column, lane_column, length_column

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
    limit); polars reads at most one row more than that.
    """
    data = data.removeprefix(_UTF8_BOM)
    names = _plain_header(data)
    if names is None or not _plain_body(data, len(names)):
        return None
    # Imported here, on the first CSV: every process imports the core, few read CSV.
    import polars as pl

    schema = {name: (pl.Float64 if name in NUMBER_COLUMNS else pl.String) for name in names}
    try:
        frame = pl.read_csv(
            data,
            has_header=False,
            skip_rows=1,
            schema=schema,
            n_rows=None if max_rows is None else max_rows + 1,
            quote_char=None,
        )
    except (pl.exceptions.PolarsError, ValueError):
        return None
    n = frame.height
    if n == 0 or (max_rows is not None and n > max_rows):
        return None
    if any(frame[name].null_count() for name in NUMBER_COLUMNS):
        return None  # an empty number: the exact reader names it
    position, velocity, timestamp = (frame[name].to_numpy() for name in NUMBER_COLUMNS)
    if not _numbers_valid(position, velocity, timestamp):
        return None
    sensors = _sensor_ids(frame, position)
    detection_ids = _detection_ids(frame)
    if sensors is None or detection_ids is None:
        return None
    features = _features(frame, n)
    if features is None:
        return None
    target = frame["target"].to_numpy() if "target" in frame.columns else np.full(n, None, object)
    return Detections(
        np.ascontiguousarray(position, dtype=np.float64),
        np.ascontiguousarray(velocity, dtype=np.float64),
        np.ascontiguousarray(timestamp, dtype=np.float64),
        sensors,
        detection_ids,
        target.astype(object, copy=False),
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


def _plain_body(data: bytes, width: int) -> bool:
    """No character whose reading the exact reader and polars might differ on, and every line
    (none blank) as wide as the header: checked over the whole file at C speed."""
    if not data.isascii() or any(c in data for c in (b'"', b"'", b" ", b"\t", b"\x0b", b"\x0c")):
        return False
    if b"\r" in data and data.count(b"\r") != data.count(b"\r\n"):
        return False
    start = 0
    while start < len(data):  # by chunks of whole lines: the check's memory stays small
        end = data.rfind(b"\n", start, start + _CHUNK_BYTES) + 1
        end = len(data) if end <= start or len(data) - start <= _CHUNK_BYTES else end
        if not _lines_as_wide(data[start:end], width):
            return False
        start = end
    return True


_CHUNK_BYTES = 1 << 22


def _lines_as_wide(chunk: bytes, width: int) -> bool:
    """Whether every line of `chunk` (whole lines; the last may lack its newline) has
    `width - 1` commas."""
    buffer = np.frombuffer(chunk, dtype=np.uint8)
    ends = np.flatnonzero(buffer == ord("\n"))
    if ends.size == 0 or ends[-1] != buffer.size - 1:
        ends = np.append(ends, buffer.size)  # the last line may end without a newline
    commas = np.flatnonzero(buffer == ord(","))
    per_line = np.diff(np.searchsorted(commas, ends), prepend=0)
    return bool(np.all(per_line == width - 1))


def _numbers_valid(position: Any, velocity: Any, timestamp: Any) -> bool:
    """What `Detections.from_columns` checks of the numbers, at once: finite, within the
    magnitude limit, positive speeds fast enough to cross the batch's road in finite time."""
    for values in (position, velocity, timestamp):
        if not bool(np.all(np.abs(values) <= MAX_ABS_VALUE)):  # NaN and inf fail too
            return False
    if not bool(np.all(velocity > 0)):
        return False
    span = float(position.max() - position.min())
    with np.errstate(divide="ignore", over="ignore"):
        return bool(np.all(span / velocity <= MAX_ABS_VALUE))


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
    # A few distinct ids: one str object each, shared by their rows (not a million copies).
    names = spread["sensor_id"].to_list()
    codes = column.cast(pl.Enum(names)).to_physical().to_numpy()
    return np.array(names, dtype=object)[codes]


def _detection_ids(frame: pl.DataFrame) -> Any:
    """The detection ids, when none is empty or repeated; d1, d2, ... without the column."""
    if "detection_id" not in frame.columns:
        return np.array([f"d{i + 1}" for i in range(frame.height)], dtype=object)
    column = frame["detection_id"]
    if column.null_count() or column.n_unique() != frame.height:
        return None
    return column.to_numpy().astype(object, copy=False)


def _features(frame: pl.DataFrame, n: int) -> dict[str, Any] | None:
    """The detector features, through the exact validators (a feature column is short work
    beside the ids); None when one has a problem."""
    problems: list[Problem] = []
    given = {
        name: frame[name].to_list() if name in frame.columns else None for name in FEATURE_COLUMNS
    }
    features = {
        "lane": lane_column(n, given["lane"], problems),
        "length": length_column(n, given["length"], problems),
        "vehicle_class": class_column(n, given["vehicle_class"], problems),
    }
    return None if problems else features
