"""A result as text, fast and byte for byte as the plain writers wrote it: the JSON that
`json.dumps(document, indent=2)` writes (the CLI's `--json`), and the target x sensor matrix
(`AssociationResult.to_matrix_csv`).

For a million detections Python's indenting JSON encoder takes tens of seconds; orjson writes
the same document in well under one. The two agree on everything a result holds except a few
forms: a float below 1e-4 in magnitude (orjson `1e-5`, `0.00001`; Python `1e-05`), which is
rewritten here to Python's spelling; text that is not printable ASCII (Python escapes it as
`\\u00e9`), and non-finite floats (Python `NaN`, orjson `null`), for which the plain encoder
writes the document. The matrix formats each column once (orjson's floats, rewritten where
they would differ from `repr`) and places each detection with numpy, instead of a `repr` and a
list per cell.
"""

from __future__ import annotations

import csv
import io
import json
import math
import re
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
import orjson

from roadlink.association.csvio import spreadsheet_safe

if TYPE_CHECKING:
    from roadlink.association.result import AssociationResult


def result_json_text(result: AssociationResult) -> str:
    """`json.dumps(result.to_dict(), indent=2) + "\\n"`: what `write_result_json` writes."""
    out = io.BytesIO()
    write_result_json(result, out)
    return out.getvalue().decode()


def write_result_json(result: AssociationResult, stream: BinaryIO) -> None:
    """Write `json.dumps(result.to_dict(), indent=2) + "\\n"` to `stream`, as UTF-8 (ASCII: the
    plain encoder escapes the rest), by orjson where the two agree, without a copy of the text.

    Whether they agree is checked on the result's arrays (the detection rows, a million of
    them, hold only its columns' values) and on the few values beside them (targets' summaries,
    parameters, metrics), not by walking a million rows. A float below 1e-4 is handed to orjson
    as a `Fragment` of its `repr`.
    """
    document = result.to_dict()
    if not _columns_agree(result):
        stream.write((json.dumps(document, indent=2) + "\n").encode())
        return
    for name in ("params", "effective_params", "metrics"):
        if name in document:
            document[name] = _respelt(document[name])
    for target in document["targets"]:
        for key, value in target.items():
            if key != "detections":
                target[key] = _respelt(value)
    if any(v is _DISAGREES for v in _walk(document, skip=("detections", "unassigned"))):
        stream.write((json.dumps(result.to_dict(), indent=2) + "\n").encode())
        return
    _respell_small_row_floats(result, document)
    stream.write(orjson.dumps(document, option=orjson.OPT_INDENT_2))
    stream.write(b"\n")


_DISAGREES = object()


def _respelt(value: Any) -> Any:
    """`value` with each float below 1e-4 as a Fragment of its `repr`, and `_DISAGREES` in
    place of what orjson writes otherwise than Python (a non-finite float, text that is not
    printable ASCII)."""
    if isinstance(value, float):
        if not math.isfinite(value):
            return _DISAGREES
        return orjson.Fragment(repr(value)) if 0 < abs(value) < 1e-4 else value
    if isinstance(value, str):
        return value if _plain_text(value) else _DISAGREES
    if isinstance(value, dict):
        if not all(map(_plain_text, value)):
            return _DISAGREES
        return {k: _respelt(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_respelt(v) for v in value]
    return value if value is None or isinstance(value, bool | int) else _DISAGREES


def _walk(value: Any, skip: tuple[str, ...]) -> Any:
    """Every value in `value`, not descending into the keys `skip`."""
    yield value
    if isinstance(value, dict):
        for key, item in value.items():
            if key not in skip:
                yield from _walk(item, skip)
    elif isinstance(value, list):
        for item in value:
            yield from _walk(item, skip)


def _columns_agree(result: AssociationResult) -> bool:
    """Whether orjson writes the detection rows' values as Python does (floats below 1e-4
    aside, which `_respell_small_row_floats` hands over as fragments)."""
    d = result.detections
    numbers = [d.position, d.velocity, d.timestamp, d.length[~np.isnan(d.length)]]
    if result.link_confidence is not None:
        numbers.append(result.link_confidence[~np.isnan(result.link_confidence)])
    texts = [d.detection_id, d.sensor_id, d.vehicle_class]
    return all(bool(np.all(np.isfinite(v))) for v in numbers) and all(
        _plain_text("".join(t for t in v.tolist() if t is not None)) for v in texts
    )


def _respell_small_row_floats(result: AssociationResult, document: dict[str, Any]) -> None:
    """Each float below 1e-4 of the detection rows as a Fragment of its `repr` (rare: road data
    is in metres and seconds; a link's confidence may be that small)."""
    d = result.detections
    columns = {"position": d.position, "velocity": d.velocity, "timestamp": d.timestamp}
    columns["length"] = d.length
    if result.link_confidence is not None:
        columns["link_confidence"] = result.link_confidence
    small = {key: np.flatnonzero((np.abs(v) < 1e-4) & (v != 0)) for key, v in columns.items()}
    if not any(rows.size for rows in small.values()):
        return
    rows = [row for target in document["targets"] for row in target["detections"]]
    rows += document["unassigned"]
    by_id = {row["detection_id"]: row for row in rows}
    for key, which in small.items():
        for i in which.tolist():
            row = by_id[d.detection_id[i]]
            if key in row:
                row[key] = orjson.Fragment(repr(float(row[key])))


def _plain_text(text: str) -> bool:
    return text.isascii() and text.isprintable()


def float_texts(values: np.ndarray) -> list[str]:
    """`repr` of every float of `values`, formatted by orjson at once (`repr` itself where orjson
    would spell it otherwise: below 1e-4 in magnitude, or not finite)."""
    items = values.tolist()
    odd = np.flatnonzero(~np.isfinite(values) | ((np.abs(values) < 1e-4) & (values != 0)))
    if odd.size:
        safe = np.where(np.isfinite(values), values, 0.0).tolist()
        texts = orjson.dumps(safe).decode()[1:-1].split(",") if items else []
        for i in odd.tolist():
            texts[i] = repr(items[i])
        return texts
    return orjson.dumps(items).decode()[1:-1].split(",") if items else []


# The cells csv.writer (QUOTE_MINIMAL) would quote: then it writes the rows itself.
_NEEDS_QUOTES = re.compile(r'[,"\r\n]')


def matrix_csv(
    result: AssociationResult,
    sensors: list[str],
    columns: dict[str, list[str]],
    write_rows: Callable[[Any], None],
) -> str:
    """The matrix of `result` (its `sensors` in road order; `columns` each detection's cells by
    field, already as text), its rows placed by numpy when every (target, sensor) cell holds at
    most one detection; else `write_rows` writes them (the general, per-cell writer)."""
    d = result.detections
    fields = list(columns)
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(
        ["target"]
        + (["confidence"] if result.link_confidence is not None else [])
        + [spreadsheet_safe(f"{sid}_{field}") for sid in sensors for field in fields]
    )
    members = result.target_members()
    n_targets, n_sensors, n_fields = len(members), len(sensors), len(fields)
    column_of = {sid: k for k, sid in enumerate(sensors)}
    sensor = np.array([column_of[s] for s in d.sensor_id.tolist()], dtype=np.int64)
    assigned = np.flatnonzero(result.groups >= 0)
    cell = result.groups[assigned] * n_sensors + sensor[assigned]
    plain = not any(_NEEDS_QUOTES.search("".join(values)) for values in columns.values())
    if (cell.size and np.bincount(cell).max() > 1) or not plain:
        write_rows(writer)
        return out.getvalue()
    # Targets are numbered in `target_members` order: the k-th distinct group is row k.
    row = np.unique(result.groups[assigned], return_inverse=True)[1].reshape(-1)
    grid = np.full((n_targets, n_sensors * n_fields), "", dtype=object)
    for f, values in enumerate(columns.values()):
        grid[row, sensor[assigned] * n_fields + f] = np.array(values, dtype=object)[assigned]
    heads = [f"T{k + 1}" for k in range(n_targets)]
    if result.link_confidence is not None:
        confidences = [result.target_confidence(m) for m in members]
        texts = float_texts(np.array(confidences, dtype=float))
        heads = [f"{h},{c}" for h, c in zip(heads, texts, strict=True)]
    for head, cells in zip(heads, grid.tolist(), strict=True):
        out.write(head + ("," if cells else "") + ",".join(cells) + "\n")
    return out.getvalue()
