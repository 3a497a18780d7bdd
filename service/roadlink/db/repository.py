"""Data functions: keyword-only, given a session; they never commit (the caller owns that)."""

from __future__ import annotations

import itertools
import uuid
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
import numpy.typing as npt
import orjson
from sqlalchemy import func, select, type_coerce
from sqlalchemy.orm import Session
from sqlalchemy.types import NullType

from roadlink.association.csvio import FEATURE_COLUMNS
from roadlink.association.detections import COLUMNS, Detections, feature_arrays
from roadlink.association.result import AssociationResult, result_from_dict
from roadlink.db.json_columns import BatchSelection, Selection, Sensor
from roadlink.db.models import Batch, Deployment, Detection, Job, JobResult, JobState

# Rows per INSERT executemany call: bounds the memory of one statement's parameters.
INSERT_CHUNK = 5_000
# The detection columns a batch insert writes (the key is the database's), in this order.
# A detection row: its batch, deployment and row number, then every column of `Detections`.
DETECTION_INSERT_COLUMNS = ("batch_id", "deployment_id", "row", *COLUMNS)


def create_deployment(session: Session, *, name: str, sensors: list[Sensor] | None) -> Deployment:
    """Add a deployment (sensors in road order, or None when not declared)."""
    deployment = Deployment(name=name, sensors=sensors)
    session.add(deployment)
    session.flush()
    return deployment


def get_deployment(session: Session, *, deployment_id: uuid.UUID) -> Deployment | None:
    """The deployment, or None."""
    return session.get(Deployment, deployment_id)


def get_batch(session: Session, *, batch_id: uuid.UUID) -> Batch | None:
    """The batch, or None."""
    return session.get(Batch, batch_id)


def insert_batch(
    session: Session,
    *,
    batch_id: uuid.UUID | None = None,
    deployment_id: uuid.UUID,
    detections: Detections,
    source: str,
    idempotency_key: str | None = None,
    idempotency_principal: str | None = None,
    request_sha256: str | None = None,
    job_id: uuid.UUID | None = None,
) -> Batch:
    """Store a validated batch; its detections go in by executemany, not one ORM object each."""
    d = detections
    batch = Batch(
        id=batch_id or uuid.uuid4(),
        deployment_id=deployment_id,
        n_detections=len(d),
        n_labelled=int(d.labelled.sum()),
        first_timestamp=float(d.timestamp.min()),
        last_timestamp=float(d.timestamp.max()),
        source=source,
        idempotency_key=idempotency_key,
        idempotency_principal=idempotency_principal,
        request_sha256=request_sha256,
        job_id=job_id,
    )
    session.add(batch)
    session.flush()
    connection = session.connection()
    dialect = connection.dialect
    table = Detection.__table__
    # The ids are bound once here, as the column type binds them (32 hex digits on SQLite, a
    # native uuid on PostgreSQL), and the rows go to the driver's executemany as plain tuples:
    # the ORM's bulk insert spent more than the database did, building and binding a dict per row.
    bind_id = table.c.batch_id.type.bind_processor(dialect) or (lambda value: value)
    batch_key, deployment_key = bind_id(batch.id), bind_id(deployment_id)
    rows = list(
        zip(
            itertools.repeat(batch_key),
            itertools.repeat(deployment_key),
            range(1, len(d) + 1),
            d.position.tolist(),
            d.velocity.tolist(),
            d.timestamp.tolist(),
            d.sensor_id.tolist(),
            d.detection_id.tolist(),
            d.target.tolist(),
            *_feature_parameters(d),
            strict=False,  # the repeats are endless; the row numbers set the length
        )
    )
    placeholder = "?" if dialect.paramstyle == "qmark" else "%s"
    names = ", ".join(dialect.identifier_preparer.quote(c) for c in DETECTION_INSERT_COLUMNS)
    statement = (
        f"INSERT INTO {dialect.identifier_preparer.format_table(table)} ({names}) "
        f"VALUES ({', '.join([placeholder] * len(DETECTION_INSERT_COLUMNS))})"
    )
    for start in range(0, len(rows), INSERT_CHUNK):
        connection.exec_driver_sql(statement, rows[start : start + INSERT_CHUNK])
    return batch


def _feature_parameters(d: Detections) -> list[Iterable[Any]]:
    """The feature columns' values as the insert binds them: NULL where not reported, and all
    NULL (no conversion at all) for a feature no detection of the batch reports."""
    reported = d.features
    return [
        d.feature_values(name) if name in reported else itertools.repeat(None)
        for name in FEATURE_COLUMNS
    ]


def count_selected_detections(
    session: Session, *, deployment_id: uuid.UUID, selection: Selection
) -> tuple[int, int]:
    """How many detections a job selection covers now, and at how many distinct positions."""
    query = select(func.count(), func.count(Detection.position.distinct())).where(
        _selects(deployment_id, selection)
    )
    n, positions = session.execute(query).one()
    return int(n or 0), int(positions or 0)


def load_detections(
    session: Session, *, deployment_id: uuid.UUID, selection: Selection
) -> Detections:
    """The detections a job selects, in upload order (batch by batch, row by row).

    A single batch comes back exactly as uploaded, so the service computes what the CLI computes
    from the same file. When several batches reuse a detection id (each gateway numbering its own
    d1, d2, ...), every id is qualified as `<batch_id>:<detection_id>` to keep them distinct.
    """
    query = (
        select(*_detection_columns())
        .join(Batch, Batch.id == Detection.batch_id)
        .where(_selects(deployment_id, selection))
        .order_by(Batch.created_at, Batch.id, Detection.row)
    )
    # Core rows (not ORM-loaded ones): the columns need no conversion but the batch id's.
    rows = list(session.connection().execute(query).all())
    batch_key = {key: str(uuid.UUID(str(key))) for key in {r[6] for r in rows}}
    if isinstance(selection, BatchSelection):  # the order the caller listed them in
        rank = {str(b): k for k, b in enumerate(selection.batch_ids)}
        rows.sort(key=lambda r: rank[batch_key[r[6]]])  # stable: keeps the row order in a batch
    n = len(rows)
    columns = list(zip(*rows, strict=True)) if rows else [()] * 10
    detection_ids = np.array(columns[4], dtype=object).reshape(n)
    if len(batch_key) > 1 and np.unique(detection_ids.astype(str)).size < n:
        detection_ids = np.array(
            [f"{batch_key[b]}:{d}" for b, d in zip(columns[6], detection_ids, strict=True)],
            dtype=object,
        )
    return _detections_of(columns, n, detection_ids)


def _detection_columns() -> tuple[Any, ...]:
    """The columns a `Detections` is read from, in the order `_detections_of` takes them."""
    return (
        Detection.position,
        Detection.velocity,
        Detection.timestamp,
        Detection.sensor_id,
        Detection.detection_id,
        Detection.target,
        # The batch id as the driver returns it: converting it to a UUID on every row cost
        # more than reading the rows. The few distinct values are converted by the caller.
        type_coerce(Detection.batch_id, NullType()),
        Detection.lane,
        Detection.length,
        Detection.vehicle_class,
    )


def _detections_of(columns: list[Any], n: int, detection_ids: Any) -> Detections:
    return Detections(
        position=np.array(columns[0], dtype=np.float64).reshape(n),
        velocity=np.array(columns[1], dtype=np.float64).reshape(n),
        timestamp=np.array(columns[2], dtype=np.float64).reshape(n),
        sensor_id=np.array(columns[3], dtype=object).reshape(n),
        detection_id=detection_ids,
        target=np.array(columns[5], dtype=object).reshape(n),
        **feature_arrays(*columns[7:10]),
    )


def _selects(deployment_id: uuid.UUID, selection: Selection) -> Any:
    condition = Detection.deployment_id == deployment_id
    if isinstance(selection, BatchSelection):
        return condition & Detection.batch_id.in_(selection.batch_ids)
    if selection.start is not None:
        condition &= Detection.timestamp >= selection.start
    if selection.end is not None:
        condition &= Detection.timestamp < selection.end
    return condition


def get_job(session: Session, *, job_id: uuid.UUID) -> Job | None:
    """The job, or None."""
    return session.get(Job, job_id)


def get_job_result(session: Session, *, job_id: uuid.UUID) -> JobResult | None:
    """A succeeded job's stored result, or None."""
    return session.get(JobResult, job_id)


def load_job_association(session: Session, *, job: Job) -> AssociationResult | None:
    """A succeeded job's result as the core's `AssociationResult` (None when it has none).

    The stored document gives every detection and its group; the true labels, which it leaves
    out, come from the job's detections (`load_detection_labels`), so the result is scored again
    and its wrongly grouped detections can be shown.
    """
    stored = get_job_result(session, job_id=job.id)
    if stored is None:
        return None
    labels = load_detection_labels(
        session, deployment_id=job.deployment_id, selection=job.selection
    )
    return result_from_dict(orjson.loads(stored.result_json), labels)


def load_detection_labels(
    session: Session, *, deployment_id: uuid.UUID, selection: Selection
) -> dict[str, str]:
    """The true labels of the detections a job selects, by the id its result gives them.

    A result names a detection by its own id, or as `<batch_id>:<detection_id>` when the job's
    batches reused ids (see `load_detections`): both forms are keys here. A bare id is left out
    when several selected batches use it, since it is then ambiguous (a time window can gain
    batches after its job ran). Unlabelled detections are left out.
    """
    query = select(Detection.detection_id, Detection.batch_id, Detection.target).where(
        _selects(deployment_id, selection)
    )
    rows = session.execute(query).all()
    uses: dict[str, int] = {}
    for detection_id, _, _ in rows:
        uses[detection_id] = uses.get(detection_id, 0) + 1
    labels: dict[str, str] = {}
    for detection_id, batch_id, target in rows:
        if target is None:
            continue
        labels[f"{batch_id}:{detection_id}"] = target
        if uses[detection_id] == 1:
            labels[detection_id] = target
    return labels


def count_jobs_by_state(session: Session) -> dict[str, int]:
    """Number of jobs in each state (every state present, zero included)."""
    counts = dict(session.execute(select(Job.state, func.count()).group_by(Job.state)).all())
    return {state.value: int(counts.get(state, 0)) for state in JobState}


def job_duration_histogram(
    session: Session, *, buckets: Sequence[float]
) -> tuple[list[int], int, float]:
    """Cumulative counts of succeeded-job durations per upper bound, their count and sum."""
    finished = Job.duration_seconds.is_not(None)
    columns = [func.count().filter(finished & (Job.duration_seconds <= b)) for b in buckets]
    row = session.execute(
        select(*columns, func.count().filter(finished), func.sum(Job.duration_seconds))
    ).one()
    values = list(row)
    return [int(v or 0) for v in values[:-2]], int(values[-2] or 0), float(values[-1] or 0.0)


@dataclass(frozen=True)
class KeyedDetections:
    """Detections with the key of each one's row (its batch id, as text, and its row number),
    which stays the same whatever window reads it. `detections.detection_id` is made unique
    as `<batch_id>:<row>`; `detection_ids` are the ids their senders gave."""

    detections: Detections
    batch_ids: npt.NDArray[np.object_]
    rows: npt.NDArray[np.int64]
    detection_ids: npt.NDArray[np.object_]


def load_detection_window(
    session: Session, *, deployment_id: uuid.UUID, start: float | None, end: float | None
) -> KeyedDetections:
    """A deployment's detections with start <= timestamp <= end (None: open), with their keys,
    in time order: the live association's window (`roadlink.queue.live_step`)."""
    condition = Detection.deployment_id == deployment_id
    if start is not None:
        condition &= Detection.timestamp >= start
    if end is not None:
        condition &= Detection.timestamp <= end
    query = (
        select(*_detection_columns(), Detection.row)
        .where(condition)
        .order_by(Detection.timestamp, Detection.batch_id, Detection.row)
    )
    rows = list(session.connection().execute(query).all())
    n = len(rows)
    columns = list(zip(*rows, strict=True)) if rows else [()] * 11
    batch_key = {key: str(uuid.UUID(str(key))) for key in set(columns[6])}
    batch_ids = np.array([batch_key[b] for b in columns[6]], dtype=object).reshape(n)
    row_numbers = np.array(columns[10], dtype=np.int64).reshape(n)
    keys = np.array([f"{b}:{r}" for b, r in zip(batch_ids, row_numbers, strict=True)], object)
    detections = _detections_of(columns, n, keys.reshape(n))
    return KeyedDetections(
        detections, batch_ids, row_numbers, np.array(columns[4], dtype=object).reshape(n)
    )
