"""The detection CSV of design.md: a header row; `position`, `velocity`, `timestamp` required;
`sensor_id`, `detection_id`, `target` optional (an empty `target` cell means unlabelled)."""

from __future__ import annotations

import csv
import io

import numpy as np

from roadlink.association.detections import DetectionError, Detections, Problem

REQUIRED_COLUMNS = ("position", "velocity", "timestamp")
OPTIONAL_COLUMNS = ("sensor_id", "detection_id", "target")


def read_detections_csv(text: str) -> Detections:
    """Parse and validate detection CSV text; DetectionError names the row and field at fault.

    Rows are numbered from 1 at the first data row (line 2 of the file).
    """
    columns = read_csv_columns(text)
    return Detections.from_columns(
        columns["position"] or [],
        columns["velocity"] or [],
        columns["timestamp"] or [],
        sensor_id=columns["sensor_id"],
        detection_id=columns["detection_id"],
        target=columns["target"],
    )


def read_csv_columns(text: str) -> dict[str, list[str | None] | None]:
    """The raw columns of a detection CSV, by name (None for an absent optional column).

    Checks the file's structure (header, field counts, quoting) but not the values: that is
    `Detections.from_columns`'s job. Empty cells become None.
    """
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")), strict=True)
    header = next(reader, None)
    if header is None or not any(h.strip() for h in header):
        raise DetectionError([Problem(None, None, "the CSV is empty: a header row is required")])
    names = [h.strip().lower() for h in header]
    missing = [c for c in REQUIRED_COLUMNS if c not in names]
    if missing:
        raise DetectionError(
            [Problem(None, c, "required column is missing from the header") for c in missing]
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
    present = {name: _cells(columns[i].tolist()) for i, name in enumerate(names) if name}
    return {name: present.get(name) for name in (*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS)}


def _cells(cells: list[str]) -> list[str | None]:
    """Stripped cells; empty ones become None (a missing number, an unlabelled target)."""
    return [cell.strip() or None for cell in cells]


def write_detections_csv(detections: Detections) -> str:
    """Detections as CSV, every column written (an unlabelled target as an empty cell)."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow([*REQUIRED_COLUMNS, *OPTIONAL_COLUMNS])
    d = detections
    for i in range(len(d)):
        writer.writerow(
            [
                repr(float(d.position[i])),
                repr(float(d.velocity[i])),
                repr(float(d.timestamp[i])),
                d.sensor_id[i],
                d.detection_id[i],
                "" if d.target[i] is None else d.target[i],
            ]
        )
    return out.getvalue()
