"""Turning a batch upload (JSON or CSV) into validated detections, or a problem naming the row.

The body is parsed once and validated once, by the core (`Detections.from_columns`,
`read_detections_csv`): the API adds nothing to what a valid detection is, except a deployment's
declared sensors.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Sequence
from typing import Any

import numpy as np
import orjson
from pydantic import BaseModel, ConfigDict, ValidationError

from service.api.errors import ApiProblem, ProblemItem, problems_from_detections
from service.api.schemas import AssociateRequest
from service.association.csvio import read_detections_csv
from service.association.detections import DetectionError, Detections, Problem

DETECTION_FIELDS = ("position", "velocity", "timestamp", "sensor_id", "detection_id", "target")
REQUIRED_FIELDS = ("position", "velocity", "timestamp")


class _Envelope(BaseModel):
    """The JSON batch without its detections' contents (those the core validates)."""

    model_config = ConfigDict(extra="forbid")

    detections: list[dict[str, Any]]
    associate: AssociateRequest | None = None


def parse_json_batch(
    body: bytes, sensors: list[dict[str, Any]] | None
) -> tuple[Detections, AssociateRequest | None]:
    """A JSON batch body into detections and the association it asks for."""
    try:
        document = orjson.loads(body)
    except orjson.JSONDecodeError as exc:
        raise ApiProblem(400, f"the body is not valid JSON: {exc}") from None
    try:
        envelope = _Envelope.model_validate(document)
    except ValidationError as exc:
        shape = [
            ProblemItem(
                field=".".join(str(p) for p in e["loc"]) or None,
                pointer="/" + "/".join(str(p) for p in e["loc"]),
                message=e["msg"],
            )
            for e in exc.errors()[:50]
        ]
        raise ApiProblem(422, "the batch is not of the documented shape", errors=shape) from None
    rows = envelope.detections
    if not rows:
        raise ApiProblem(
            422,
            "the batch has no detections",
            errors=[ProblemItem(field="detections", pointer="/detections", message="is empty")],
        )
    items: list[ProblemItem] = []
    for i, row in enumerate(rows):
        for name in row.keys() - DETECTION_FIELDS:
            items.append(_row_item(i, name, f"unknown field; known: {', '.join(DETECTION_FIELDS)}"))
        for name in REQUIRED_FIELDS:
            if row.get(name) is None:
                items.append(_row_item(i, name, "is required"))
        for name in DETECTION_FIELDS[3:]:
            value = row.get(name)
            if value is not None and not isinstance(value, str):
                items.append(_row_item(i, name, f"must be a string, got {value!r}"))
        if len(items) >= 100:
            break
    if items:
        raise ApiProblem(422, _count(items), errors=items)
    columns = {name: [row.get(name) for row in rows] for name in DETECTION_FIELDS}
    with_sensors = _fill_declared_sensors(columns, sensors, json_body=True)
    return validate_columns(with_sensors, "/detections"), envelope.associate


def parse_csv_batch(body: bytes, sensors: list[dict[str, Any]] | None) -> Detections:
    """A detection CSV body (design.md's format) into detections."""
    try:
        text = body.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise ApiProblem(400, f"the CSV is not UTF-8 text: {exc}") from None
    try:
        detections = read_detections_csv(text)
    except DetectionError as exc:
        if not _only_one_position(exc):
            raise ApiProblem(
                422, _count(exc.problems), errors=problems_from_detections(exc.problems)
            ) from None
    else:
        if sensors is None:
            return detections
    # The file is well-formed (the core read it); the declared sensors are checked against the
    # sensor ids as written in it, not as the core generated them from position rank.
    columns = _csv_columns(text)
    return validate_columns(_fill_declared_sensors(columns, sensors, json_body=False), None)


def validate_columns(columns: dict[str, Any], json_prefix: str | None) -> Detections:
    """The core's validation of raw columns, as problem details.

    A batch may hold a single sensor's detections (one gateway per sensor is common; a job joins
    the batches), although the core needs two sensor positions to associate. When that is the
    only objection, the batch is validated with one extra detection at another position, which
    is then dropped: every real detection still passes the core's checks, and the job checks
    the two positions when it runs.
    """
    try:
        return Detections.from_columns(**columns)
    except DetectionError as exc:
        if not _only_one_position(exc):
            raise ApiProblem(
                422,
                _count(exc.problems),
                errors=problems_from_detections(exc.problems, json_prefix=json_prefix),
            ) from None
    n = len(columns["position"])
    only = _as_float(columns["position"][0])
    padded: dict[str, Any] = {
        "position": [*columns["position"], (only or 0.0) + 1.0],
        "velocity": [*columns["velocity"], 1.0],
        "timestamp": [*columns["timestamp"], 0.0],
    }
    for name in ("sensor_id", "detection_id"):
        values = columns.get(name)
        # An id no real input holds (it starts with a NUL character), so it cannot collide.
        padded[name] = None if values is None else [*values, "\0padding"]
    target = columns.get("target")
    padded["target"] = None if target is None else [*target, None]
    return Detections.from_columns(**padded).take(np.arange(n))


def _only_one_position(error: DetectionError) -> bool:
    return [(p.row, p.field) for p in error.problems] == [(None, "position")] and (
        "two distinct sensor positions" in error.problems[0].message
    )


def _csv_columns(text: str) -> dict[str, Any]:
    """The columns of a CSV the core has already read without objection (same conventions:
    lower-cased header, blank lines skipped, empty cells absent)."""
    reader = csv.reader(io.StringIO(text.lstrip("\ufeff")))
    header = [h.strip().lower() for h in next(reader)]
    rows = [row for row in reader if any(cell.strip() for cell in row)]
    columns: dict[str, Any] = dict.fromkeys(DETECTION_FIELDS)
    for k, name in enumerate(header):
        if name in DETECTION_FIELDS:
            columns[name] = [row[k].strip() or None for row in rows]
    return columns


def _fill_declared_sensors(
    columns: dict[str, Any], sensors: list[dict[str, Any]] | None, *, json_body: bool
) -> dict[str, Any]:
    """With declared sensors: every detection must name a declared sensor at its position, and
    a detection without a sensor id takes the one declared at its position."""
    if sensors is None:
        return columns
    by_id = {s["sensor_id"]: float(s["position"]) for s in sensors}
    by_position = {float(s["position"]): s["sensor_id"] for s in sensors}
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
