"""The detection CSV: a header row; `position`, `velocity`, `timestamp` required; `sensor_id`,
`detection_id`, `target` optional (an empty `target` cell means unlabelled), and so are the
detector features `lane`, `length` and `vehicle_class` (an empty cell: not reported).

Every CSV roadlink writes may be opened in a spreadsheet, which runs a cell that starts with `=`,
`+`, `-`, `@`, a tab or a carriage return as a formula (CSV injection). Text cells (ids and
labels, never numbers) that start so are written with a leading `'`, as OWASP recommends (and a
text that starts with `'` gets one more); the reader drops that quote again, so that a file
roadlink wrote reads back as it was.
"""

from __future__ import annotations

import csv
import io
import mmap
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from roadlink.association.detections import DetectionError, Detections, Problem
from roadlink.association.fast_csv import (
    UTF8_BOM,
    fast_detections,
    plain_detections,
    plain_layout,
)
from roadlink.association.text_columns import prefixed

if TYPE_CHECKING:
    import polars as pl

# What a spreadsheet takes for the start of a formula.
FORMULA_STARTS = ("=", "+", "-", "@", "\t", "\r")

REQUIRED_COLUMNS = ("position", "velocity", "timestamp")
FEATURE_COLUMNS = ("lane", "length", "vehicle_class")
OPTIONAL_COLUMNS = ("sensor_id", "detection_id", "target", *FEATURE_COLUMNS)
# As a JSON batch refuses an unknown field, a CSV refuses an unknown column: a misspelt
# `sensorid` must not be dropped in silence.
KNOWN = (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)

# What `read_detections_csv` imports on first use (its fast path's parser), kept out of
# `import roadlink` as the associators' solvers are (`Associator.imports_on_first_use`).
READER_IMPORTS = ("polars",)
# Up to this many bytes, a process that has not loaded the fast path's parser reads with the
# exact reader: loading polars takes 0.2-0.3 s, the exact reader 10 us a row (50 ms here, about
# 4,700 rows of 55 bytes; both on the 2-core AMD EPYC development machine). It reads any file as
# the fast path does (tests/association/test_fast_csv.py).
SMALL_BYTES = 1 << 18


def reader_imports(size: int | None) -> tuple[str, ...]:
    """What reading CSV of `size` bytes (None: unknown) will import: nothing for a small one,
    which the exact reader takes where polars is not loaded yet (`SMALL_BYTES`)."""
    return () if size is not None and size <= SMALL_BYTES else READER_IMPORTS


def _exact_is_quicker(size: int) -> bool:
    return size <= SMALL_BYTES and "polars" not in sys.modules


class TooManyRows(DetectionError):
    """The CSV has more data rows than the reader was allowed to read."""

    def __init__(self, max_rows: int) -> None:
        super().__init__([Problem(max_rows + 1, None, f"is beyond the {max_rows} rows allowed")])
        self.max_rows = max_rows


def read_detections_csv(text: str | bytes | Path) -> Detections:
    """Parse and validate detection CSV text (its UTF-8 bytes, or the file at a path);
    DetectionError names the row and field at fault (UnicodeDecodeError for bytes that are not
    UTF-8, OSError for a file that cannot be read).

    Rows are numbered from 1 at the first data row (line 2 of the file). A plain, valid file is
    read by the fast path (`fast_csv`); any other is read again here, which names every problem.
    A small one is read here at once where polars is not loaded yet (`SMALL_BYTES`).
    A file is mapped into memory for the fast path, not read into a copy (a tenth of a 10^6-row
    read); a file of no bytes cannot be mapped, and is read.
    """
    if isinstance(text, Path):
        return _read_file(text)
    if not _exact_is_quicker(len(text)):
        fast = fast_detections(text if isinstance(text, bytes) else text.encode("utf-8"))
        if fast is not None:
            return fast
    return read_detections_csv_exactly(
        text.decode("utf-8-sig") if isinstance(text, bytes) else text
    )


def _read_file(path: Path) -> Detections:
    """`read_detections_csv` of the file at `path`, mapped for the fast path; one that cannot
    be mapped (no bytes: empty, or a pipe) or starts with a byte-order mark, read as bytes."""
    with path.open("rb") as file:
        size = os.fstat(file.fileno()).st_size
        if not size or _exact_is_quicker(size):
            return read_detections_csv(file.read())
        if file.read(len(UTF8_BOM)) == UTF8_BOM:
            file.seek(0)
            return read_detections_csv(file.read())
        # The map is closed before polars maps the file: one map of it at a time.
        with mmap.mmap(file.fileno(), 0, access=mmap.ACCESS_READ) as mapped:
            layout = plain_layout(mapped)
        fast = None if layout is None else plain_detections(path, layout)
        if fast is not None:
            return fast
        file.seek(0)
        return read_detections_csv_exactly(file.read().decode("utf-8"))


def read_detections_csv_exactly(text: str) -> Detections:
    """What `read_detections_csv` reads, by the exact reader alone (Python's `csv`), which
    names every problem: the reader of any file the fast path does not take."""
    columns = read_csv_columns(text)
    return Detections.from_columns(
        columns["position"] or [],
        columns["velocity"] or [],
        columns["timestamp"] or [],
        sensor_id=columns["sensor_id"],
        detection_id=columns["detection_id"],
        target=columns["target"],
        lane=columns["lane"],
        length=columns["length"],
        vehicle_class=columns["vehicle_class"],
    )


def read_csv_columns(text: str, max_rows: int | None = None) -> dict[str, list[str | None] | None]:
    """The raw columns of a detection CSV, by name (None for an absent optional column).

    Checks the file's structure (header, field counts, quoting) but not the values: that is
    `Detections.from_columns`'s job. Empty cells become None. With `max_rows`, reading stops at
    the first row beyond it, which is then the error: the cost is bounded by the limit, not by
    the file.
    """
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")), strict=True)
    try:
        header = next(reader, None)
    except csv.Error as exc:  # an unterminated quote in the header, say
        raise DetectionError([Problem(None, None, f"the header is not valid CSV: {exc}")]) from None
    if header is None or not any(h.strip() for h in header):
        raise DetectionError([Problem(None, None, "the CSV is empty: a header row is required")])
    names = [h.strip().lower() for h in header]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise DetectionError(
            [Problem(None, c, "required column is missing from the header") for c in missing]
        )
    unknown = [n or f"(column {k + 1}, unnamed)" for k, n in enumerate(names) if n not in KNOWN]
    if unknown:
        known = ", ".join(KNOWN)
        raise DetectionError(
            [Problem(None, n, f"unknown column; the known columns are: {known}") for n in unknown]
        )
    duplicated = sorted({n for n in names if names.count(n) > 1 and n})
    if duplicated:
        raise DetectionError(
            [Problem(None, c, "column appears more than once in the header") for c in duplicated]
        )
    width = len(names)
    rows: list[list[str]] = []
    problems: list[Problem] = []
    try:
        for row in reader:
            if not any(cell.strip() for cell in row):
                continue  # blank lines carry nothing
            if max_rows is not None and len(rows) == max_rows:
                raise TooManyRows(max_rows)
            if len(row) != width:
                problems.append(
                    Problem(len(rows) + 1, None, f"has {len(row)} fields, the header has {width}")
                )
            rows.append(row)
    except csv.Error as exc:
        problems.append(Problem(len(rows) + 1, None, f"is not valid CSV: {exc}"))
    if problems:
        raise DetectionError(problems)
    if not rows:
        raise DetectionError([Problem(None, None, "the CSV has a header but no detections")])
    columns = np.array(rows, dtype=object).T
    present = {name: _cells(columns[i].tolist()) for i, name in enumerate(names)}
    return {name: present.get(name) for name in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)}


def _cells(cells: list[str]) -> list[str | None]:
    """Stripped cells, unescaped (see `spreadsheet_safe`); empty ones become None (a missing
    number, an unlabelled target)."""
    return [_unescaped(cell.strip()) or None for cell in cells]


def spreadsheet_safe(text: str) -> str:
    """A text cell that a spreadsheet shows as text, never runs as a formula. A text that starts
    with a quote gets one more, so that reading it back gives it as it was."""
    return "'" + text if text.startswith(_ESCAPED) else text


def spreadsheet_safe_texts(texts: list[str]) -> list[str]:
    """`spreadsheet_safe` of each of `texts` (a million ids, say): as they are when none needs
    the quote, which one search of their joined text tells."""
    joined = "\n" + "\n".join(texts)
    if any("\n" + start in joined for start in _ESCAPED):
        return [spreadsheet_safe(text) for text in texts]
    return texts


def spreadsheet_safe_column(texts: pl.Series) -> pl.Series:
    """`spreadsheet_safe` of each of `texts`, a polars String column (no nulls), at once."""
    return prefixed(texts, _ESCAPED, "'")


def _unescaped(cell: str) -> str:
    return cell[1:] if cell.startswith("'") and cell[1:].startswith(_ESCAPED) else cell


_ESCAPED = (*FORMULA_STARTS, "'")


def write_detections_csv(detections: Detections) -> str:
    """Detections as CSV (an unlabelled target as an empty cell). A feature column is written
    when some detection reports it, with empty cells where others do not, so that detections
    without features are written exactly as before features existed."""
    d = detections
    features = d.features
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*REQUIRED_COLUMNS, "sensor_id", "detection_id", "target", *features])
    feature_cells = [feature_cells_of(d, name) for name in features]
    for i in range(len(d)):
        writer.writerow(
            [
                repr(float(d.position[i])),
                repr(float(d.velocity[i])),
                repr(float(d.timestamp[i])),
                spreadsheet_safe(d.sensor_id[i]),
                spreadsheet_safe(d.detection_id[i]),
                _text_cell(d.target[i]),
                *(cells[i] for cells in feature_cells),
            ]
        )
    return out.getvalue()


def feature_cells_of(detections: Detections, name: str) -> list[str]:
    """One feature column as CSV cells: empty where not reported, text made spreadsheet safe."""
    values = detections.feature_values(name)
    if name == "lane":
        return ["" if v is None else str(v) for v in values]
    if name == "length":
        return ["" if v is None else repr(v) for v in values]
    return [_text_cell(v) for v in values]


def _text_cell(text: object) -> str:
    return "" if text is None else spreadsheet_safe(str(text))
