"""A result as text, fast and byte for byte as the plain writers wrote it: the JSON that
`json.dumps(document, indent=2)` writes (the CLI's `--json`), and the service's stored JSON
(the target x sensor matrix is `matrix_text`'s; it formats floats by `float_texts`).

For a million detections Python's indenting JSON encoder takes tens of seconds; orjson writes
the same document in well under one. The two agree on everything a result holds except a few
forms: a float below 1e-4 in magnitude (orjson `1e-5`, `0.00001`; Python `1e-05`), which is
rewritten here to Python's spelling; text that is not printable ASCII (Python escapes it as
`\\u00e9`), and non-finite floats (Python `NaN`, orjson `null`), for which the plain encoder
writes the document.
"""

from __future__ import annotations

import io
import json
import math
import re
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace
from itertools import pairwise
from typing import TYPE_CHECKING, Any, BinaryIO

import numpy as np
import orjson

from roadlink.association.text_columns import (
    encoded_rows,
    float_column,
    has_any,
    joined_columns,
    joined_rows,
    made_in_order,
    text_column,
    where,
)

if TYPE_CHECKING:
    from roadlink.association.detections import Detections
    from roadlink.association.result import AssociationResult
    from roadlink.association.scores import Metrics


def result_json_text(result: AssociationResult, texts: DetectionTexts | None = None) -> str:
    """`json.dumps(result.to_dict(), indent=2) + "\\n"`: what `write_result_json` writes."""
    out = io.BytesIO()
    write_result_json(result, out, texts)
    return out.getvalue().decode()


def write_result_json(
    result: AssociationResult,
    stream: BinaryIO,
    texts: DetectionTexts | None = None,
    metrics: Callable[[], Metrics | None] | None = None,
) -> None:
    """Write `json.dumps(result.to_dict(), indent=2) + "\\n"` to `stream`, as UTF-8 (ASCII: the
    plain encoder escapes the rest), a few targets at a time, without the row objects.
    `texts`, when given, are `json_detection_texts` of the result's detections (made while
    they were associated). `metrics`, when given, gives the metrics in place of the result's,
    and is called only once the rows are written: the metrics come last in the document, so
    an unscored result (`build_result(..., scored=False)`) can be scored meanwhile.

    orjson writes the document with a hole for each target's detections and for the unassigned
    ones; their text is written into the holes from the columns (`_filled`), a batch of
    rows at a time. Whether orjson and the rows' text agree with the plain encoder is checked
    on the result's arrays and on the few values beside them (targets' summaries, parameters,
    metrics), not by walking a million rows; a float below 1e-4 is handed to orjson as a
    `Fragment` of its `repr`. Where they would not agree, the plain encoder writes it.
    """
    holes: list[Any] = []
    document = result.document(_holes_into(holes))
    if texts is None or texts.detections is not result.detections or texts.layout != _INDENTED:
        texts = DetectionTexts(result.detections, _INDENTED)
    rows = _RowTexts(result, texts)
    try:
        if not rows.agree:
            raise _Disagrees
        for name in ("params", "effective_params", "metrics"):
            if name in document:
                document[name] = _respelt(document[name])
        _respell_targets(document["targets"])
    except _Disagrees:
        if metrics is not None:
            result = replace(result, metrics=metrics())
        stream.write((json.dumps(result.to_dict(), indent=2) + "\n").encode())
        return
    if metrics is not None:
        document["metrics"] = _METRICS_HOLE
    text = orjson.dumps(document, option=orjson.OPT_INDENT_2).decode()
    text, _, end = text.rpartition(_METRICS_HOLE_TEXT) if metrics is not None else (text, "", "")
    for chunk in _filled_bytes(text, holes, rows):
        stream.write(chunk)
    if metrics is not None:
        stream.write((_metrics_text(metrics()) + end).encode())
    stream.write(b"\n")


def _metrics_text(metrics: Metrics | None) -> str:
    """The document's `metrics` value as `json.dumps(indent=2)` writes it in the document (a
    key of the top level): the plain encoder's own text, six numbers at most."""
    text = json.dumps({"metrics": None if metrics is None else metrics.to_dict()}, indent=2)
    return text[len('{\n  "metrics": ') : -len("\n}")]


def json_detection_texts(detections: Detections) -> DetectionTexts:
    """What `write_result_json` takes of `detections` alone, made before their grouping is
    known (see `DetectionTexts.prepared`)."""
    return DetectionTexts(detections, _INDENTED).prepared()


def result_json_compact(result: AssociationResult) -> str:
    """`orjson.dumps(result.to_dict()).decode()`, the same text (the service's stored result),
    written as `write_result_json` writes its own: orjson writes the document with holes, the
    rows' text is joined from the columns into them. orjson's own spelling throughout, so no
    value needs respelling; only where the rows' text would not be orjson's (text that is not
    printable ASCII, a value that is not finite) does orjson write the row objects."""
    rows = _RowTexts(result, DetectionTexts(result.detections, _COMPACT))
    if not rows.agree:
        return orjson.dumps(result.to_dict()).decode()
    holes: list[Any] = []
    text = orjson.dumps(result.document(_holes_into(holes))).decode()
    return "".join(_filled(text, holes, rows))


def _holes_into(holes: list[Any]) -> Callable[[Any], Any]:
    """`document`'s `detections_of`: a hole in the text for each list of rows, `holes` their
    indices in document order (each target's, then the unassigned ones)."""

    def hole(members: Any) -> Any:
        holes.append(members)
        return _HOLE

    return hole


def _filled(text: str, holes: list[Any], rows: _RowTexts) -> Iterator[str]:
    """`text` (orjson's, with a hole for each of `holes`) with the holes' rows written in, a
    batch of targets at a time. No text orjson writes holds a NUL (it escapes control
    characters): the holes do."""
    batches, last = _filling(text, holes)
    if rows.polars:
        yield from made_in_order(lambda batch: rows.text(*batch), batches)
    else:
        yield from (rows.text(*batch) for batch in batches)
    yield last


def _filled_bytes(text: str, holes: list[Any], rows: _RowTexts) -> Iterator[bytes]:
    """`_filled`, as UTF-8: each batch encoded where it is made."""
    batches, last = _filling(text, holes)
    if rows.polars:
        yield from made_in_order(lambda batch: rows.encoded(*batch), batches)
    else:
        yield from (rows.encoded(*batch) for batch in batches)
    yield last.encode()


def _filling(text: str, holes: list[Any]) -> tuple[list[Any], str]:
    """`text`'s batches of holes to fill, as `_RowTexts.text` takes them, and the text after
    the last: whole targets, about `_BATCH_ROWS` rows a batch, then the unassigned rows."""
    pieces = text.split(_HOLE_TEXT)
    unassigned = holes.pop()
    batches = [
        (pieces[start:end], holes[start:end], TARGET_ROWS_INDENT)
        for start, end in pairwise([0, *_batches(holes)])
    ]
    batches.append(([pieces[-2]], [unassigned], 4))
    return batches, pieces[-1]


_HOLE_TEXT = "\x00"
_HOLE = orjson.Fragment(_HOLE_TEXT.encode())
# The metrics' place, when they are written last (`write_result_json`'s `metrics`).
_METRICS_HOLE_TEXT = "\x01"
_METRICS_HOLE = orjson.Fragment(_METRICS_HOLE_TEXT.encode())
_BATCH_ROWS = 1 << 16


def _batches(holes: list[Any]) -> list[int]:
    """Where each batch of holes ends: whole targets, about `_BATCH_ROWS` rows a batch (what
    the rows' text costs in memory at once)."""
    if not holes:
        return []
    sizes = np.cumsum([h.size for h in holes])
    ends = np.searchsorted(sizes, np.arange(_BATCH_ROWS, sizes[-1], _BATCH_ROWS), side="right")
    return sorted({*(int(e) for e in ends if e > 0), len(holes)})


@dataclass(frozen=True)
class _Layout:
    """Where the rows' text breaks lines and what follows a key: `json.dumps(indent=2)`'s (and
    orjson's `OPT_INDENT_2`), or orjson's compact text."""

    indented: bool
    colon: str

    def line(self, indent: int) -> str:
        """What starts an element at `indent` spaces: a new line, or nothing when compact."""
        return "\n" + " " * indent if self.indented else ""

    def key(self, indent: int, name: str) -> str:
        return self.line(indent) + f'"{name}"' + self.colon


_INDENTED = _Layout(indented=True, colon=": ")
_COMPACT = _Layout(indented=False, colon=":")


class DetectionTexts:
    """What the rows' text takes of the detections alone, before their grouping is known: the
    texts of the ids and sensor ids, whether they need escaping, and (`prepared`) each row's
    text from its id to its timestamp, made at once for every detection. From `_POLARS_ROWS`
    rows polars makes them (`text_columns`: no Python object per value); below, where polars'
    fixed cost per call (about a millisecond) would outweigh the rows, Python lists do (a
    paper-size job's result is written in the service's every job)."""

    def __init__(self, detections: Detections, layout: _Layout) -> None:
        self.detections = detections
        self.layout = layout
        # orjson's compact floats are its own spelling; the indented text is Python's.
        self.spelling = "python" if layout.indented else "orjson"
        self.polars = len(detections) >= _POLARS_ROWS
        self.ids, self.sensors = self._parsed("detection_id"), self._parsed("sensor_id")
        # Ids are never None; the constant text around them quotes them, when none needs
        # escaping (else they are JSON strings already). Plain ids, the common case, are told
        # by one search for either kind of character.
        plain = not self._holds(r'[^ -~]|["\\]')
        self.agree = _columns_agree(detections) and (plain or not self._holds(_NOT_PRINTABLE_ASCII))
        self.quote = '"'
        if self.agree and not plain:
            self.quote = ""
            self.ids = self._texts(_json_strings(detections.detection_id))
            self.sensors = self._texts(_json_strings(detections.sensor_id))
        self._prepared: dict[int, Any] = {}

    def prepared(self) -> DetectionTexts:
        """These texts with the rows of the targets' detections made for every detection
        (polars only; a target's detections are most of them), so that writing a result
        only gathers them: on a thread beside the association, that leaves the writer only
        what the grouping decides (the CLI's --json)."""
        if self.polars and self.agree:
            inner = TARGET_ROWS_INDENT + 2
            everyone = np.arange(len(self.detections))
            self._prepared[inner] = joined_columns(self._columns(everyone, inner))
        return self

    def columns(self, index: Any, inner: int) -> list[Any]:
        """The text of rows `index` from their id to their timestamp (the id's key and quote
        before them are not included), keys at `inner` spaces: as parts for `joined_rows`."""
        prepared = self._prepared.get(inner)
        if prepared is not None:
            return [prepared.gather(index)]
        return self._columns(index, inner)

    def _columns(self, index: Any, inner: int) -> list[Any]:
        d, layout, q = self.detections, self.layout, self.quote
        return [
            self._gather(self.ids, index),
            q + "," + layout.key(inner, "sensor_id") + q,
            self._gather(self.sensors, index),
            q + "," + layout.key(inner, "position"),
            self.floats(d.position[index]),
            "," + layout.key(inner, "velocity"),
            self.floats(d.velocity[index]),
            "," + layout.key(inner, "timestamp"),
            self.floats(d.timestamp[index]),
        ]

    def _parsed(self, name: str) -> Any:
        """The texts of the ids or sensor ids: in polars, the CSV parser's own column when it
        made one (no str per row to turn into polars)."""
        parsed = self.detections.parsed_texts(name) if self.polars else None
        return parsed if parsed is not None else self._texts(getattr(self.detections, name))

    def _texts(self, values: Any) -> Any:
        return text_column(values) if self.polars else values

    def _holds(self, pattern: str) -> bool:
        """Whether an id or a sensor id holds a match of `pattern`."""
        if self.polars:
            return has_any(self.ids, pattern) or has_any(self.sensors, pattern)
        texts = "".join(self.ids.tolist()) + "".join(set(self.sensors.tolist()))
        return re.search(pattern, texts) is not None

    def _gather(self, texts: Any, index: Any) -> Any:
        return texts.gather(index) if self.polars else texts[index].tolist()

    def floats(self, values: Any) -> Any:
        if self.polars:
            return float_column(values, spelling=self.spelling)
        return float_texts(values, spelling=self.spelling)


# The indent of a target's detection rows in the indented JSON (`{` of each row).
TARGET_ROWS_INDENT = 8


class _RowTexts:
    """The text of the detection rows, as `json.dumps(indent=2)` writes them (or orjson's
    compact text, by `layout`), from the columns: each column's text made at once (or taken
    from `DetectionTexts`), the constant text between them given once, and all rows joined
    at once."""

    def __init__(self, result: AssociationResult, texts: DetectionTexts) -> None:
        self.result = result
        self.texts = texts
        self.layout = texts.layout
        self.polars = texts.polars
        links = result.link_confidence
        self.agree = texts.agree and (links is None or bool(np.all(~np.isinf(links))))
        self.linked = None if links is None else (result.groups >= 0) & ~np.isnan(links)

    def text(self, pieces: list[str], holes: list[Any], indent: int) -> str:
        """Each of `pieces` followed by the JSON list of its hole's rows (indices into the
        detections; their `{` at `indent` spaces), as one text. Only a last hole may be empty."""
        parts, tail = self._parts(pieces, holes, indent)
        if not parts:
            return tail
        if self.polars:
            return joined_rows(parts, tail)
        rows = len(parts[0])
        return _interleaved([p if isinstance(p, list) else [p] * rows for p in parts]) + tail

    def encoded(self, pieces: list[str], holes: list[Any], indent: int) -> bytes:
        """`text`, as UTF-8 (polars' rows without a Python str between)."""
        parts, tail = self._parts(pieces, holes, indent) if self.polars else ([], "")
        return encoded_rows(parts, tail) if parts else self.text(pieces, holes, indent).encode()

    def _parts(self, pieces: list[str], holes: list[Any], indent: int) -> tuple[list[Any], str]:
        """`text`'s rows as parts for `joined_rows`, and the text after them; no parts, and
        the whole text, when there are no rows."""
        index = np.concatenate(holes)
        if index.size == 0:
            return [], "".join(p + "[]" for p in pieces)
        layout = self.layout
        inner = indent + 2
        opening = layout.line(indent) + "{" + layout.key(inner, "detection_id") + self.texts.quote
        close_row, close_list = layout.line(indent) + "}", layout.line(indent - 2) + "]"
        lead = ["," + opening] * index.size
        start = 0
        for k, (piece, members) in enumerate(zip(pieces, holes, strict=True)):
            lead[start] = (close_list if k else "") + piece + "[" + opening
            start += members.size
        parts = [lead, *self.texts.columns(index, inner), *self._extra(index, inner, close_row)]
        return parts, close_list

    def _extra(self, index: Any, inner: int, close_row: str) -> list[Any]:
        """What follows a row's timestamp: its features, when the input has them, its link's
        confidence where it has one, and the row's closing brace."""
        extra: list[Any] = []
        features = self.result.detections.features
        if features:  # rare beside a million rows: a string per row is fine
            cells = np.full(index.size, "", dtype=object)
            for name in features:
                cells = cells + ("," + self.layout.key(inner, name)) + self._feature(name, index)
            extra.append(cells.tolist())
        if self.linked is None or self.result.link_confidence is None:
            return [*extra, close_row]
        linked = self.linked[index]
        links = np.where(linked, self.result.link_confidence[index], 0.0)  # no NaN to spell
        prefix = "," + self.layout.key(inner, "link_confidence")
        if self.polars:
            return [
                *extra,
                where(linked, [prefix, self.texts.floats(links), close_row], close_row),
            ]
        spelling = self.texts.spelling
        texts = np.array(float_texts(links, prefix, close_row, spelling), dtype=object)
        return [*extra, np.where(linked, texts, close_row).tolist()]

    def _feature(self, name: str, index: Any) -> Any:
        """A feature's cells of the rows `index`, as JSON (null where not reported)."""
        values = getattr(self.result.detections, name)[index]
        if name == "lane":
            cells = np.array([str(v) for v in values.tolist()], dtype=object)
            cells[values < 0] = "null"
        elif name == "length":
            cells = np.array(float_texts(values, spelling=self.texts.spelling), dtype=object)
            cells[np.isnan(values)] = "null"
        else:
            cells = _json_strings(values)
        return cells


# From this many detections the rows' text is made by polars (see `_RowTexts`); a test sets it
# to 0 and to a billion, to check the two ways write the same bytes.
_POLARS_ROWS = 10_000


def _interleaved(columns: list[list[str]]) -> str:
    """The cells of `columns` (of one length) row by row, as one text: placed into one list by
    slice assignment (a C loop each), a fifth faster than joining `zip`'s tuples."""
    k = len(columns)
    cells: list[str] = [""] * (k * len(columns[0]))
    for j, column in enumerate(columns):
        cells[j::k] = column
    return "".join(cells)


def _json_strings(values: Any) -> Any:
    """Each value of an object array of text (or None) as JSON text (printable ASCII: the
    plain encoder and orjson write the same), as an object array; each distinct value once."""
    items = values.tolist()
    texts = {v: _json_string(v) for v in set(items)}
    return np.array(list(map(texts.__getitem__, items)), dtype=object).reshape(values.shape)


def _json_string(value: Any) -> str:
    return "null" if value is None else orjson.dumps(value).decode()


class _Disagrees(Exception):
    """orjson would write a value otherwise than the plain encoder."""


def _respelt(value: Any) -> Any:
    """`value` with each float below 1e-4 as a Fragment of its `repr`; `_Disagrees` for what
    orjson writes otherwise than Python (a non-finite float, text that is not printable
    ASCII)."""
    if value is None or isinstance(value, bool | int):
        return value
    if isinstance(value, float):
        if not math.isfinite(value):
            raise _Disagrees
        return orjson.Fragment(repr(value)) if 0 < abs(value) < 1e-4 else value
    if isinstance(value, str):
        if not _plain_text(value):
            raise _Disagrees
        return value
    if isinstance(value, dict):
        if not all(map(_plain_text, value)):
            raise _Disagrees
        return {k: _respelt(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_respelt(v) for v in value]
    raise _Disagrees


def _respell_targets(targets: list[dict[str, Any]]) -> None:
    """`_respelt` each target's values but its detections: its name (`T1`, printable ASCII)
    as it is, its confidences (20,000 at 10^6 detections) checked at once and respelt only
    when one would need it."""
    confidences = [t["confidence"] for t in targets if "confidence" in t]
    values = np.array(confidences, dtype=float)
    common = bool(np.all(np.isfinite(values) & ((values == 0) | (np.abs(values) >= 1e-4))))
    for target in targets:
        for key, value in target.items():
            if key not in ("target", "detections") and not (key == "confidence" and common):
                target[key] = _respelt(value)


def _columns_agree(d: Detections) -> bool:
    """Whether the detection rows' numbers and classes are written alike by the plain encoder
    and here: finite numbers, printable ASCII text (the ids: see `DetectionTexts`)."""
    numbers = [d.position, d.velocity, d.timestamp, d.length[~np.isnan(d.length)]]
    classes = _plain_text("".join(filter(None, set(d.vehicle_class.tolist()))))
    return classes and all(bool(np.all(np.isfinite(v))) for v in numbers)


# What `_plain_text` refuses, as a pattern.
_NOT_PRINTABLE_ASCII = r"[^ -~]"


def _plain_text(text: str) -> bool:
    return text.isascii() and text.isprintable()


def float_texts(
    values: np.ndarray, prefix: str = "", suffix: str = "", spelling: str = "python"
) -> list[str]:
    """`prefix + repr(v) + suffix` for every float v of `values`, formatted by orjson at once,
    from the array itself (the same text as from Python floats, at twice the speed; `repr`
    itself where orjson would spell it otherwise: below 1e-4 in magnitude, or not finite).
    With `spelling="orjson"`, orjson's own text of each finite value, as `orjson.dumps` of
    the Python float writes it (`1e-5`, not `1e-05`); for finite values only."""
    if values.size == 0:
        return []
    array = np.ascontiguousarray(values, dtype=np.float64)
    if spelling == "orjson":
        odd = np.array([], dtype=np.int64)
    else:
        odd = np.flatnonzero(~np.isfinite(array) | ((np.abs(array) < 1e-4) & (array != 0)))
    safe = np.where(np.isfinite(array), array, 0.0) if odd.size else array
    text = orjson.dumps(safe, option=orjson.OPT_SERIALIZE_NUMPY).decode()[1:-1]
    if prefix or suffix:  # the affixes in one pass over the text, not one per value
        text = prefix + text.replace(",", suffix + "\x00" + prefix) + suffix
        texts = text.split("\x00")
    else:
        texts = text.split(",")
    for i in odd.tolist():
        texts[i] = prefix + repr(float(array[i])) + suffix
    return texts
