"""The target x sensor matrix of a result (`AssociationResult.to_matrix_csv`), byte for byte as
`csv.writer` writes it cell by cell.

When every (target, sensor) cell holds at most one detection and no cell needs quoting (the
common case), each field's column is formatted once and the rows are joined from the columns
at once: from `_POLARS_ROWS` detections by polars (`text_columns`: no Python object per value;
0.43 s for 10^6 detections against 1.2 s from lists, AMD EPYC), below by Python lists placed
with numpy (polars' fixed cost of about a millisecond a call would outweigh a paper-size job's
matrix, which the service writes for every job). Otherwise the rows are written cell by cell.
"""

from __future__ import annotations

import csv
import io
import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from roadlink.association.csvio import (
    feature_cells_of,
    spreadsheet_safe,
    spreadsheet_safe_column,
    spreadsheet_safe_texts,
)
from roadlink.association.result_text import float_texts
from roadlink.association.text_columns import (
    concatenated,
    float_column,
    has_any,
    joined,
    text_column,
    where,
)

if TYPE_CHECKING:
    from roadlink.association.detections import Detections, IntArray, ObjectArray
    from roadlink.association.result import AssociationResult

# The cells csv.writer (QUOTE_MINIMAL) would quote (and NUL, which it may refuse): then it
# writes the rows itself.
_NEEDS_QUOTES = re.compile(r'[,"\r\n\x00]')
_NUMBER_FIELDS = frozenset(("velocity", "timestamp", "link_confidence", "lane", "length"))

# From this many placed detections polars joins the rows (see the module's text); a test sets
# it to 0 and to a billion, to check the two ways write the same bytes.
_POLARS_ROWS = 10_000


def matrix_csv(result: AssociationResult) -> str:
    """The matrix of `result` (see `AssociationResult.to_matrix_csv`)."""
    d = result.detections
    sensors, sensor, ordered = _sensor_columns(d)
    fields = ["detection_id", "velocity", "timestamp"]
    fields += ["link_confidence"] if result.link_confidence is not None else []
    fields += list(d.features)
    out = io.StringIO()
    csv.writer(out, lineterminator="\n").writerow(
        ["target"]
        + (["confidence"] if result.link_confidence is not None else [])
        + [spreadsheet_safe(f"{sid}_{field}") for sid in sensors for field in fields]
    )
    header = out.getvalue()
    if not np.any(result.groups >= 0):
        return header
    placement = _placed(result, sensor, len(sensors))
    text = None
    if placement is not None:
        heads = _heads(result, placement, ordered)
        heads[0] = header + heads[0]
        if placement.order.size >= _POLARS_ROWS:
            text = _joined_by_polars(result, len(fields), placement, heads)
        else:
            text = _joined_by_lists(result, len(fields), placement, heads)
    return _cell_by_cell(result, len(sensors), sensor, header) if text is None else text


@dataclass(frozen=True)
class _Placement:
    """Where the assigned detections go: `order`, them in the matrix's order (row by row,
    sensor by sensor), `cells` each one's cell (row * n_sensors + its sensor's column), and
    `sizes` each row's count of them."""

    n_targets: int
    n_sensors: int
    order: IntArray
    cells: IntArray
    sizes: IntArray

    @property
    def full(self) -> bool:
        """Whether every target has a detection at every sensor."""
        return self.cells.size == self.n_targets * self.n_sensors


def _placed(result: AssociationResult, sensor: IntArray, n_sensors: int) -> _Placement | None:
    """Where the assigned detections go in the matrix; None when a cell holds several. Each
    detection's index is written into its cell of a table as large as the matrix (whose text
    is longer still): the cells taken, in order, are the detections sorted by cell, without a
    sort."""
    assigned = np.flatnonzero(result.groups >= 0)
    row = _rows(result.groups[assigned])
    n_targets = int(row.max()) + 1
    slot = np.full(n_targets * n_sensors, -1, dtype=np.int64)
    slot[row * n_sensors + sensor[assigned]] = np.arange(assigned.size)
    cells = np.flatnonzero(slot >= 0)
    if cells.size < assigned.size:  # a cell of several detections
        return None
    sizes = np.bincount(row, minlength=n_targets)
    return _Placement(n_targets, n_sensors, assigned[slot[cells]], cells, sizes)


def _rows(groups: IntArray) -> IntArray:
    """Each group's row: targets are numbered in `target_members` order, the k-th distinct
    group is row k. A result's groups are its rows (`build_result` numbers them 0, 1, ...):
    that is checked by a count, not a sort."""
    if groups.max() < groups.size and np.all(np.bincount(groups)):
        return groups
    return np.unique(groups, return_inverse=True)[1].reshape(-1)


def _heads(result: AssociationResult, placement: _Placement, ordered: bool) -> list[str]:
    """Each row's cells before its first sensor's: the target's name, and its confidence
    when the associator gives them."""
    heads = [f"T{k + 1}" for k in range(placement.n_targets)]
    if result.link_confidence is None:
        return heads
    if ordered:  # `order` is each target's members, target after target
        confidences = result.link_products(placement.order, placement.sizes)
    else:
        confidences = result.target_confidences(result.target_members())
    texts = float_texts(np.array(confidences, dtype=float))
    return [f"{h},{c}" for h, c in zip(heads, texts, strict=True)]


def _joined_by_lists(
    result: AssociationResult, n_fields: int, placement: _Placement, heads: list[str]
) -> str | None:
    """The rows as one text, each detection's cells formatted once (Python strs), placed by
    numpy; a row's line break and the next row's head are appended to its last cell. None
    when a cell needs quoting."""
    columns = _cell_lists(result, placement.order)
    if any(
        _NEEDS_QUOTES.search("".join(values))
        for field, values in columns.items()
        if field not in _NUMBER_FIELDS  # numbers hold none of those characters
    ):
        return None
    row_width = placement.n_sensors * n_fields
    n_targets = placement.n_targets
    if placement.full:
        texts = np.empty(n_targets * row_width, dtype=object)
        for f, values in enumerate(columns.values()):
            texts[f::n_fields] = values
    else:
        texts = np.full(n_targets * row_width, "", dtype=object)
        for f, values in enumerate(columns.values()):
            texts[placement.cells * n_fields + f] = values
    ends = np.arange(1, n_targets + 1) * row_width - 1
    breaks = np.array([f"\n{h}" for h in heads[1:]] + ["\n"], dtype=object)
    texts[ends] = texts[ends] + breaks
    texts[0] = f"{heads[0]},{texts[0]}"
    return ",".join(texts.tolist())


def _joined_by_polars(
    result: AssociationResult, n_fields: int, placement: _Placement, heads: list[str]
) -> str | None:
    """The rows as one text, joined by polars from one column of texts in the text's order:
    each row's head (after a line break, but the first), then each of its cells (a target at
    a sensor), as "," and the detection's fields joined by ",", or the empty fields. None when
    a cell needs quoting."""
    import polars as pl

    columns = _cell_columns(result, placement.order)
    if any(
        has_any(values, _NEEDS_QUOTES.pattern)
        for field, values in columns.items()
        if field not in _NUMBER_FIELDS
    ):
        return None
    cells = pl.select(concatenated(["", *columns.values()], ",")).to_series()
    empty = text_column(["," * n_fields])
    texts = pl.concat([cells, empty, text_column([heads[0], *("\n" + h for h in heads[1:])])])
    return joined(texts.gather(_text_order(placement)), "\n")


def _text_order(placement: _Placement) -> IntArray:
    """Where each text of the matrix is among the placed detections' cells, the empty cell and
    the rows' heads (`_joined_by_polars`), in the text's order: row by row, its head and then
    its cells."""
    n_placed, n_sensors, cells = placement.order.size, placement.n_sensors, placement.cells
    index = np.full(placement.n_targets * (n_sensors + 1), n_placed)
    index[:: n_sensors + 1] = n_placed + 1 + np.arange(placement.n_targets)
    index[cells + cells // n_sensors + 1] = np.arange(n_placed)
    return index


def _cell_lists(result: AssociationResult, index: IntArray | None) -> dict[str, list[str]]:
    """Each field's cells of the detections `index` (all, in order, when None), as Python
    strs, each column formatted at once (`float_texts`: `repr` of each, by orjson)."""
    d = result.detections

    def of(values: Any) -> Any:
        return values if index is None else values[index]

    columns = {
        "detection_id": spreadsheet_safe_texts(of(d.detection_id).tolist()),
        "velocity": float_texts(of(d.velocity)),
        "timestamp": float_texts(of(d.timestamp)),
    }
    if result.link_confidence is not None:
        link = of(result.link_confidence)
        links = float_texts(link)
        for i in np.flatnonzero(np.isnan(link)).tolist():
            links[i] = ""
        columns["link_confidence"] = links
    for name in d.features:
        columns[name] = of(np.array(feature_cells_of(d, name), dtype=object)).tolist()
    return columns


def _cell_columns(result: AssociationResult, order: IntArray) -> dict[str, Any]:
    """`_cell_lists(result, order)` as polars String columns (the link's confidences as an
    expression). The ids are the CSV parser's column when it made them; a column of Python
    strs (ids, features) is made in input order and then gathered: made in the matrix's order,
    its strs would be read from all over memory (130 ms against 20 for 10^6 ids, AMD EPYC)."""
    d = result.detections
    parsed = d.parsed_texts("detection_id")
    ids = text_column(d.detection_id) if parsed is None else parsed
    ids = spreadsheet_safe_column(ids.gather(order))
    columns: dict[str, Any] = {
        "detection_id": ids,
        "velocity": float_column(d.velocity[order]),
        "timestamp": float_column(d.timestamp[order]),
    }
    if result.link_confidence is not None:
        link = result.link_confidence[order]
        linked = ~np.isnan(link)
        columns["link_confidence"] = where(linked, [float_column(np.where(linked, link, 0))], "")
    for name in d.features:
        columns[name] = text_column(feature_cells_of(d, name)).gather(order)
    return columns


def _cell_by_cell(result: AssociationResult, n_sensors: int, sensor: IntArray, header: str) -> str:
    """The rows written by csv.writer cell by cell: a cell may list several detections
    (possible with K-means), separated by ';'."""
    out = io.StringIO()
    out.write(header)
    writer = csv.writer(out, lineterminator="\n")
    values = list(_cell_lists(result, None).values())
    sensor_of = sensor.tolist()
    members = result.target_members()
    confidences = result.target_confidences(members)
    for k, (of_target, confidence) in enumerate(zip(members, confidences, strict=True)):
        cells: list[list[list[str]]] = [[[] for _ in values] for _ in range(n_sensors)]
        for i in of_target.tolist():
            for cell, of_field in zip(cells[sensor_of[i]], values, strict=True):
                cell.append(of_field[i])
        head = [f"T{k + 1}"] + ([] if confidence is None else [repr(confidence)])
        writer.writerow(head + [";".join(v) for cell in cells for v in cell])
    return out.getvalue()


def _sensor_columns(d: Detections) -> tuple[list[str], IntArray, bool]:
    """The distinct sensor ids by their (lowest) position, then by id; each detection's index
    in that order; and whether each sensor has one position and no two sensors share one (then
    detections ordered by sensor are in road order, as `target_members` orders them)."""
    names, codes = _sensor_codes(d.sensor_id)
    lowest = np.full(len(names), np.inf)
    lowest[codes] = d.position
    one_each = bool(np.array_equal(lowest[codes], d.position))
    if not one_each:
        lowest = np.full(len(names), np.inf)
        np.minimum.at(lowest, codes, d.position)
    road = sorted(range(len(names)), key=lambda k: (lowest[k], str(names[k])))
    column = np.empty(len(names), dtype=np.int64)
    column[road] = np.arange(len(names))
    distinct = bool(np.all(np.diff(lowest[road]) > 0))
    return [names[k] for k in road], column[codes], one_each and distinct


def _sensor_codes(ids: ObjectArray) -> tuple[list[str], IntArray]:
    """The distinct sensor ids in order of first appearance, and each detection's index among
    them. Detections come sensor by sensor (a gateway's file, the simulator's): each run of
    one sensor's is looked up once, not each detection (7 ms against 45 for 10^6 detections,
    AMD EPYC; the same object compares equal at once). Detections in no such order cost 20 ms
    more."""
    if not ids.size:
        return [], np.zeros(0, dtype=np.int64)
    starts = np.flatnonzero(np.concatenate(([True], ids[1:] != ids[:-1])))
    run_ids = ids[starts].tolist()
    names = list(dict.fromkeys(run_ids))  # a few distinct ids: sorted as Python, not per row
    code = {name: k for k, name in enumerate(names)}
    run_codes = np.fromiter(map(code.__getitem__, run_ids), np.int64, len(run_ids))
    return names, np.repeat(run_codes, np.diff(np.append(starts, ids.size)))
