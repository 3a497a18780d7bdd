"""Turning a batch upload (JSON or CSV) into validated detections, or a problem naming the row.

The body is parsed once and validated once, by the core (`Detections.from_columns`,
`read_csv_columns`): the API adds nothing to what a valid detection is, except a deployment's
declared sensors.
"""

from __future__ import annotations

from collections.abc import Sequence
from itertools import repeat
from typing import Any

import numpy as np
import orjson
from pydantic import BaseModel, ConfigDict, ValidationError

from roadlink.api.errors import (
    ApiProblem,
    malformed_json,
    problems_from_detections,
    validation_item,
)
from roadlink.api.json_detections import decode_rows, row_columns
from roadlink.api.schemas import AssociateRequest
from roadlink.association.csvio import FEATURE_COLUMNS, TooManyRows, read_csv_columns
from roadlink.association.detections import DetectionError, Detections, Problem
from roadlink.association.fast_csv import fast_detections
from roadlink.association.feature_columns import json_floats
from roadlink.db.json_columns import Sensor
from roadlink.services.problems import ProblemItem

REQUIRED_FIELDS = ("position", "velocity", "timestamp")
TEXT_FIELDS = ("sensor_id", "detection_id", "target", "vehicle_class")
# Detector features that are numbers: null or absent means "not reported".
OPTIONAL_NUMBER_FIELDS = ("lane", "length")
DETECTION_FIELDS = (*REQUIRED_FIELDS, "sensor_id", "detection_id", "target", *FEATURE_COLUMNS)


class _Envelope(BaseModel):
    """The JSON batch without its detections' contents (those the core validates)."""

    model_config = ConfigDict(extra="forbid")

    detections: list[dict[str, Any]]
    associate: AssociateRequest | None = None


def parse_json_batch(
    body: bytes, sensors: list[Sensor] | None, max_detections: int
) -> tuple[Detections, AssociateRequest | None]:
    """A JSON batch body into detections and the association it asks for (at most
    `max_detections`, counted before any detection is validated).

    A well-formed, valid body is read by the fast path (`json_detections`); any other is read
    again by the exact path, which names every problem."""
    fast = _fast_json_batch(body, sensors, max_detections)
    return fast if fast is not None else _exact_json_batch(body, sensors, max_detections)


def _exact_json_batch(
    body: bytes, sensors: list[Sensor] | None, max_detections: int
) -> tuple[Detections, AssociateRequest | None]:
    """`parse_json_batch` by orjson and each column's types, naming every problem."""
    try:
        document = orjson.loads(body)
    except orjson.JSONDecodeError as exc:
        raise malformed_json(exc.msg, document=exc.doc, position=exc.pos) from None
    rows, associate = _envelope(document)
    if len(rows) > max_detections:
        raise too_many_detections(len(rows), max_detections)
    if not rows:
        raise ApiProblem(
            422,
            "the batch has no detections",
            errors=[ProblemItem(field="detections", pointer="/detections", message="is empty")],
        )
    # Gathered by map (C speed), not a comprehension per field.
    columns: dict[str, Any] = {
        name: list(map(dict.get, rows, repeat(name))) for name in DETECTION_FIELDS
    }
    well_formed = _well_formed(rows, columns)
    if not well_formed:
        items = _shape_problems(rows)
        if items:
            raise ApiProblem(422, _count(items), errors=items)
    for name in FEATURE_COLUMNS:  # reported by no detection: spare the core a per-row check
        if columns[name].count(None) == len(rows):
            columns[name] = None
    for name in OPTIONAL_NUMBER_FIELDS:
        # JSON numbers and null (checked above) as floats at once, NaN for null: what the core
        # takes as "not reported", checked there as a whole. A value beyond the limit keeps
        # the list, whose check names it as before.
        floats = json_floats(columns[name]) if well_formed and columns[name] else None
        if floats is not None:
            columns[name] = floats
    with_sensors = _fill_declared_sensors(columns, sensors, json_body=True)
    return validate_columns(with_sensors, "/detections"), associate


def _fast_json_batch(
    body: bytes, sensors: list[Sensor] | None, max_detections: int
) -> tuple[Detections, AssociateRequest | None] | None:
    """What the exact path makes of a body msgspec reads as rows of the documented types, or
    None for any body the exact path must read (and refuse) itself."""
    decoded = decode_rows(body)
    if decoded is None:
        return None
    rows, raw_associate = decoded
    if not rows or len(rows) > max_detections:
        return None
    try:
        document = {} if raw_associate is None else {"associate": orjson.loads(raw_associate)}
        associate = _Envelope.model_validate({"detections": [], **document}).associate
        columns = _fill_declared_sensors(row_columns(rows), sensors, json_body=True)
        return Detections.from_columns(**columns), associate
    except (orjson.JSONDecodeError, ValidationError, ApiProblem, DetectionError):
        return None


def _envelope(document: Any) -> tuple[list[dict[str, Any]], AssociateRequest | None]:
    """The detections (each a JSON object, not yet validated) and the association asked for.

    The common case is checked at C speed and only `associate` goes through pydantic: handing
    it the detections too copied every one of them. Anything else goes through pydantic whole,
    for its problems."""
    detections = document.get("detections") if isinstance(document, dict) else None
    if type(detections) is list and set(map(type, detections)) <= {dict}:
        try:
            envelope = _Envelope.model_validate({**document, "detections": []})
        except ValidationError as exc:
            raise _shape_problem(exc) from None
        return detections, envelope.associate
    try:
        envelope = _Envelope.model_validate(document)
    except ValidationError as exc:
        raise _shape_problem(exc) from None
    return envelope.detections, envelope.associate


def _shape_problem(exc: ValidationError) -> ApiProblem:
    shape = [validation_item(e["loc"], e["msg"]) for e in exc.errors()[:50]]
    return ApiProblem(422, "the batch is not of the documented shape", errors=shape)


def too_many_detections(count: int | str, limit: int) -> ApiProblem:
    """The problem of a batch past the detections one batch may hold."""
    return ApiProblem(
        422,
        f"the batch has {count} detections, past the {limit} that one batch may hold "
        "(ROADLINK_MAX_BATCH_DETECTIONS); split it into smaller batches",
        errors=[ProblemItem(field="detections", message="too many detections")],
    )


def _well_formed(rows: list[dict[str, Any]], columns: dict[str, list[Any]]) -> bool:
    """True when no row has an unknown field, a number field that is not a JSON number (text
    such as "30" included) or a text field that is not text: the common case, checked column by
    column at C speed (the row-by-row check that names each problem runs only when this is
    false)."""
    return (
        # Every row's field names in one set (each row's test against the known names, with
        # its temporary set, took twice as long and grew with the fields a row has).
        set().union(*rows) <= _KNOWN_FIELDS
        and all(set(map(type, columns[name])) <= _NUMBER for name in REQUIRED_FIELDS)
        and all(
            set(map(type, columns[name])) <= _OPTIONAL_NUMBER for name in OPTIONAL_NUMBER_FIELDS
        )
        and all(set(map(type, columns[name])) <= _OPTIONAL_TEXT for name in TEXT_FIELDS)
    )


_KNOWN_FIELDS = frozenset(DETECTION_FIELDS)
# Exact JSON value types (bool is an int to Python, not a number to JSON).
_NUMBER = {int, float}
_OPTIONAL_NUMBER = {int, float, type(None)}
_OPTIONAL_TEXT = {str, type(None)}


def _shape_problems(rows: list[dict[str, Any]]) -> list[ProblemItem]:
    """The problems (the first hundred) of rows that are not well formed, each named."""
    items: list[ProblemItem] = []
    for i, row in enumerate(rows):
        for name in row.keys() - DETECTION_FIELDS:
            items.append(_row_item(i, name, f"unknown field; known: {', '.join(DETECTION_FIELDS)}"))
        for name in REQUIRED_FIELDS:
            value = row.get(name)
            if value is None:
                items.append(_row_item(i, name, "is required"))
            elif type(value) not in _NUMBER:
                items.append(_row_item(i, name, f"must be a JSON number, got {value!r}"))
        for name in OPTIONAL_NUMBER_FIELDS:
            value = row.get(name)
            if type(value) not in _OPTIONAL_NUMBER:
                items.append(_row_item(i, name, f"must be a JSON number or null, got {value!r}"))
        for name in TEXT_FIELDS:
            value = row.get(name)
            if value is not None and not isinstance(value, str):
                items.append(_row_item(i, name, f"must be a string, got {value!r}"))
        if len(items) >= 100:
            break
    return items


def parse_csv_batch(body: bytes, sensors: list[Sensor] | None, max_detections: int) -> Detections:
    """A detection CSV body into detections; reading stops past `max_detections` rows."""
    fast = fast_detections(body, max_rows=max_detections)
    if fast is not None and _declared_sensors_agree(fast, sensors):
        return fast
    try:
        text = body.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ApiProblem(400, f"the CSV is not UTF-8 text: {exc}") from None
    try:
        columns = read_csv_columns(text, max_rows=max_detections)
    except TooManyRows:
        raise too_many_detections(f"more than {max_detections}", max_detections) from None
    except DetectionError as exc:
        raise ApiProblem(
            422, _count(exc.problems), errors=problems_from_detections(exc.problems)
        ) from None
    # Declared sensors are checked against the sensor ids as written in the file, not as the
    # core would generate them from position rank.
    return validate_columns(_fill_declared_sensors(columns, sensors, json_body=False), None)


def validate_columns(columns: dict[str, Any], json_prefix: str | None) -> Detections:
    """The core's validation of raw columns, as problem details."""
    try:
        return Detections.from_columns(**columns)
    except DetectionError as exc:
        raise ApiProblem(
            422,
            _count(exc.problems),
            errors=problems_from_detections(exc.problems, json_prefix=json_prefix),
        ) from None


def _declared_sensors_agree(detections: Detections, sensors: list[Sensor] | None) -> bool:
    """True when every sensor of `detections` is declared at its position and is the one
    declared there: then `_fill_declared_sensors` would neither object nor fill anything."""
    if sensors is None:
        return True
    by_id = {s.sensor_id: s.position for s in sensors}
    by_position = {s.position: s.sensor_id for s in sensors}
    pairs = set(zip(detections.sensor_id.tolist(), detections.position.tolist(), strict=True))
    return all(by_id.get(sid) == pos and by_position.get(pos) == sid for sid, pos in pairs)


def _fill_declared_sensors(
    columns: dict[str, Any], sensors: list[Sensor] | None, *, json_body: bool
) -> dict[str, Any]:
    """With declared sensors: every detection must name a declared sensor at its position, and
    a detection without a sensor id takes the one declared at its position."""
    if sensors is None:
        return columns
    by_id = {s.sensor_id: s.position for s in sensors}
    by_position = {s.position: s.sensor_id for s in sensors}
    positions = columns["position"]
    given = columns["sensor_id"] or [None] * len(positions)
    filled: list[str | None] = []
    items: list[ProblemItem] = []
    for i, (sensor, position) in enumerate(zip(given, positions, strict=True)):
        number = _as_float(position)
        if sensor is None:
            name = by_position.get(number) if number is not None else None
            if name is None and number is not None:
                items.append(
                    _row_item(
                        i,
                        "position",
                        f"no declared sensor is at position {number:g} and no sensor_id is given",
                        json_body,
                    )
                )
            filled.append(name)
        elif sensor not in by_id:
            items.append(
                _row_item(
                    i,
                    "sensor_id",
                    f"unknown sensor '{sensor}'; this deployment declares: "
                    + ", ".join(sorted(by_id)),
                    json_body,
                )
            )
            filled.append(sensor)
        else:
            if number is not None and number != by_id[sensor]:
                items.append(
                    _row_item(
                        i,
                        "position",
                        f"sensor '{sensor}' is declared at position {by_id[sensor]:g}, "
                        f"not {number:g}",
                        json_body,
                    )
                )
            filled.append(sensor)
        if len(items) >= 100:
            break
    if items:
        raise ApiProblem(422, _count(items), errors=items)
    return {**columns, "sensor_id": filled}


def _as_float(value: object) -> float | None:
    if isinstance(value, bool) or value is None:
        return None
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return None
    return number if np.isfinite(number) else None


def _row_item(index: int, field: str, message: str, json_body: bool = True) -> ProblemItem:
    pointer = f"/detections/{index}/{field}" if json_body else None
    return ProblemItem(row=index + 1, field=field, pointer=pointer, message=message)


def _count(items: Sequence[ProblemItem | Problem]) -> str:
    """A one-line summary: how many detections are invalid, and the first problem."""
    rows = {i.row for i in items if i.row is not None}
    first = min(items, key=lambda i: (i.row is None, i.row or 0))
    where = f"field '{first.field}': " if first.field else ""
    if not rows:
        return "; ".join(
            f"field '{i.field}': {i.message}" if i.field else i.message for i in items[:5]
        )
    count = f"{len(rows)} detection is" if len(rows) == 1 else f"{len(rows)} detections are"
    row = f"row {first.row}, " if first.row is not None else ""
    return f"{count} invalid; the first: {row}{where}{first.message}"
