"""The schema. A batch's detections are stored as one columnar block (`DetectionBlock`)."""

from __future__ import annotations

import uuid
from datetime import UTC, datetime
from typing import Any, ClassVar

from sqlalchemy import (
    JSON,
    BigInteger,
    DateTime,
    Dialect,
    Float,
    ForeignKey,
    Index,
    Integer,
    LargeBinary,
    MetaData,
    String,
    Text,
    TypeDecorator,
    UniqueConstraint,
    Uuid,
)
from sqlalchemy.orm import DeclarativeBase, Mapped, mapped_column

from roadlink.db.enums import ApiKeyScope as ApiKeyScope  # a key's `scope`, by its name here too
from roadlink.db.enums import JobState
from roadlink.db.json_columns import Selection, SelectionType, Sensor, SensorsType

# Stable constraint names, so that migrations can refer to them on every database.
NAMING_CONVENTION = {
    "ix": "ix_%(column_0_label)s",
    "uq": "uq_%(table_name)s_%(column_0_name)s",
    "ck": "ck_%(table_name)s_%(constraint_name)s",
    "fk": "fk_%(table_name)s_%(column_0_name)s_%(referred_table_name)s",
    "pk": "pk_%(table_name)s",
}


def utcnow() -> datetime:
    """The current time, timezone-aware UTC (every timestamp the service stores is UTC)."""
    return datetime.now(UTC)


class UTCDateTime(TypeDecorator[datetime]):
    """A UTC timestamp on every database.

    SQLite has no time zones: values are stored as naive UTC and come back aware, so comparisons
    such as `lease_expires_at < now` mean the same on SQLite and PostgreSQL.
    """

    impl = DateTime(timezone=True)
    cache_ok = True

    def process_bind_param(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        if value.tzinfo is None:
            raise ValueError("naive datetime given; the service stores UTC only")
        value = value.astimezone(UTC)
        return value.replace(tzinfo=None) if dialect.name == "sqlite" else value

    def process_result_value(self, value: datetime | None, dialect: Dialect) -> datetime | None:
        if value is None:
            return None
        return value.replace(tzinfo=UTC) if value.tzinfo is None else value.astimezone(UTC)


# SQLite only auto-increments an INTEGER PRIMARY KEY; PostgreSQL gets a BIGINT identity.
DetectionKey = BigInteger().with_variant(Integer(), "sqlite")


class Base(DeclarativeBase):
    metadata = MetaData(naming_convention=NAMING_CONVENTION)
    type_annotation_map: ClassVar[dict[Any, Any]] = {
        datetime: UTCDateTime(),
        dict[str, Any]: JSON(),
        uuid.UUID: Uuid(),
    }


class JobStateType(TypeDecorator[JobState]):
    """A job's state: stored as its text (a plain VARCHAR, so no migration and any SQL reads
    it), read back as a `JobState`; text that is no state is refused before it is written."""

    impl = String(20)
    cache_ok = True

    def process_bind_param(self, value: JobState | str | None, dialect: Dialect) -> str | None:
        return None if value is None else JobState(value).value

    def process_result_value(self, value: str | None, dialect: Dialect) -> JobState | None:
        return None if value is None else JobState(value)


class Deployment(Base):
    """A stretch of road with its sensors; batches and jobs belong to one."""

    __tablename__ = "deployment"

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    name: Mapped[str] = mapped_column(String(200))
    # In road order, or None when sensors are not declared.
    sensors: Mapped[list[Sensor] | None] = mapped_column(SensorsType())
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class Batch(Base):
    """One upload of detections (JSON or CSV, or a simulation)."""

    __tablename__ = "batch"
    __table_args__ = (
        # An Idempotency-Key is the sender's, on this deployment's batches endpoint.
        UniqueConstraint(
            "deployment_id",
            "idempotency_principal",
            "idempotency_key",
            name="uq_batch_idempotency_scope",
        ),
        # Time windows: the deployment's batches whose span reaches past a window's start.
        Index("ix_batch_deployment_id_last_timestamp", "deployment_id", "last_timestamp"),
    )

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE"), index=True
    )
    n_detections: Mapped[int] = mapped_column(Integer)
    n_labelled: Mapped[int] = mapped_column(Integer)
    first_timestamp: Mapped[float] = mapped_column(Float)
    last_timestamp: Mapped[float] = mapped_column(Float)
    source: Mapped[str] = mapped_column(String(20))  # json | csv | simulation
    idempotency_key: Mapped[str | None] = mapped_column(String(200))
    # Who sent the key: the API key's id, or "anonymous" when authentication is disabled.
    idempotency_principal: Mapped[str | None] = mapped_column(String(64))
    # sha256 of the request, so that a reused key with a different body is told apart.
    request_sha256: Mapped[str | None] = mapped_column(String(64))
    # The job enqueued with the batch (`associate` in the upload), in the same transaction.
    job_id: Mapped[uuid.UUID | None] = mapped_column(ForeignKey("job.id", ondelete="SET NULL"))
    # Indexed for ROADLINK_RETENTION_DAYS, which deletes the oldest batches.
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)


class DetectionBlock(Base):
    """A batch's detections, column by column in upload order, as one block
    (`roadlink.db.detection_blocks`): row r of the batch is entry r - 1. A time window reads the
    blocks of the batches whose span overlaps it (`Batch.first_timestamp`, `last_timestamp`)."""

    __tablename__ = "detection_block"

    batch_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("batch.id", ondelete="CASCADE"), primary_key=True
    )
    # The distinct sensor ids of the batch, sorted (listings show them without the block).
    sensors: Mapped[list[str]] = mapped_column(JSON)
    data: Mapped[bytes] = mapped_column(LargeBinary)


class Job(Base):
    """An association to run: which detections, with which associator, and where it stands."""

    __tablename__ = "job"
    __table_args__ = (
        # The claim query: the oldest runnable queued job.
        Index("ix_job_state_run_after", "state", "run_after"),
    )

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE"), index=True
    )
    selection: Mapped[Selection] = mapped_column(SelectionType())
    associator: Mapped[str] = mapped_column(String(100))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    state: Mapped[JobState] = mapped_column(JobStateType(), default=JobState.QUEUED)
    progress: Mapped[float] = mapped_column(Float, default=0.0)
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    max_attempts: Mapped[int] = mapped_column(Integer)
    run_after: Mapped[datetime] = mapped_column(default=utcnow)
    lease_owner: Mapped[str | None] = mapped_column(String(200))
    lease_expires_at: Mapped[datetime | None] = mapped_column()
    error: Mapped[str | None] = mapped_column(Text)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    started_at: Mapped[datetime | None] = mapped_column()
    # Indexed for ROADLINK_RETENTION_DAYS, which deletes the jobs that finished long ago.
    finished_at: Mapped[datetime | None] = mapped_column(index=True)
    duration_seconds: Mapped[float | None] = mapped_column(Float)
    # How many detections the job covered (known once it ran).
    n_detections: Mapped[int | None] = mapped_column(Integer)
    # The id of the request that created the job (X-Request-ID), so that the worker's log lines
    # for the job carry it; None for a job made outside a request.
    request_id: Mapped[str | None] = mapped_column(String(128))


class JobResult(Base):
    """A succeeded job's result, written in the transaction that marks the job succeeded."""

    __tablename__ = "job_result"

    job_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("job.id", ondelete="CASCADE"), primary_key=True
    )
    # orjson's text of AssociationResult.to_dict() (result_json_compact), served as is.
    result_json: Mapped[str] = mapped_column(Text)
    matrix_csv: Mapped[str] = mapped_column(Text)
    accuracy: Mapped[float | None] = mapped_column(Float)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class ApiKey(Base):
    """A bearer key. Only its sha256 is stored; the key itself is shown once, when created."""

    __tablename__ = "api_key"

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    # The public part of the key (`rl_<prefix>_<secret>`), to find the row and to name the key in
    # logs and listings without revealing anything that authenticates.
    prefix: Mapped[str] = mapped_column(String(16), unique=True)
    secret_sha256: Mapped[str] = mapped_column(String(64))
    name: Mapped[str | None] = mapped_column(String(200))
    scope: Mapped[str] = mapped_column(String(20))
    # For `ingest` keys: the deployment ids (strings) it may post to; null for the other scopes.
    deployment_ids: Mapped[list[str] | None] = mapped_column(JSON)
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    revoked_at: Mapped[datetime | None] = mapped_column()


class JobIdempotencyKey(Base):
    """The job a `POST /v1/jobs` with an Idempotency-Key created, so that a retry gets that job
    back instead of a second one. Keys are scoped to the API key that sent them."""

    __tablename__ = "job_idempotency_key"

    # The API key's id, or "anonymous" when authentication is disabled.
    principal: Mapped[str] = mapped_column(String(64), primary_key=True)
    idempotency_key: Mapped[str] = mapped_column(String(200), primary_key=True)
    request_sha256: Mapped[str] = mapped_column(String(64))
    job_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("job.id", ondelete="CASCADE"))
    created_at: Mapped[datetime] = mapped_column(default=utcnow, index=True)


class LiveAssociation(Base):
    """A deployment's live association (issue 18): how it associates, where its data clock
    stands, and who owns its next step. One row per deployment, kept when stopped so that a
    restart continues its vehicle numbering and never publishes a detection twice."""

    __tablename__ = "live_association"

    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE"), primary_key=True
    )
    associator: Mapped[str] = mapped_column(String(100))
    params: Mapped[dict[str, Any]] = mapped_column(JSON)
    lateness: Mapped[float] = mapped_column(Float)
    active: Mapped[bool] = mapped_column(default=True)
    # The newest detection timestamp received (None before the first batch).
    data_clock: Mapped[float | None] = mapped_column(Float)
    # The farthest sensor position seen: where every vehicle leaves the road.
    road_end: Mapped[float | None] = mapped_column(Float)
    # Batches stored since it started, and how many of them the last step had seen: a step is
    # due while they differ (a late batch changes no clock but must still be associated).
    received: Mapped[int] = mapped_column(Integer, default=0)
    processed: Mapped[int] = mapped_column(Integer, default=0)
    # Flushes asked for and done: a flush is due while they differ.
    flush_requested: Mapped[int] = mapped_column(Integer, default=0)
    flushed: Mapped[int] = mapped_column(Integer, default=0)
    # Every detection older than `floor` is settled (published, left unassigned, or late).
    floor: Mapped[float | None] = mapped_column(Float)
    # The data clock the last step ran at, and what it left open.
    step_clock: Mapped[float | None] = mapped_column(Float)
    open_tracks: Mapped[int] = mapped_column(Integer, default=0)
    open_detections: Mapped[int] = mapped_column(Integer, default=0)
    next_vehicle: Mapped[int] = mapped_column(Integer, default=1)
    vehicles_published: Mapped[int] = mapped_column(Integer, default=0)
    late_detections: Mapped[int] = mapped_column(Integer, default=0)
    lease_owner: Mapped[str | None] = mapped_column(String(200))
    lease_expires_at: Mapped[datetime | None] = mapped_column()
    created_at: Mapped[datetime] = mapped_column(default=utcnow)
    last_step_at: Mapped[datetime | None] = mapped_column()


class LiveVehicle(Base):
    """A vehicle the live association published; `seq` is the feed's cursor."""

    __tablename__ = "live_vehicle"
    __table_args__ = (
        UniqueConstraint(
            "deployment_id", "vehicle_id", "revision", name="uq_live_vehicle_revision"
        ),
        Index("ix_live_vehicle_deployment_id_seq", "deployment_id", "seq"),
    )

    seq: Mapped[int] = mapped_column(DetectionKey, primary_key=True, autoincrement=True)
    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE")
    )
    vehicle_id: Mapped[str] = mapped_column(String(40))
    revision: Mapped[int] = mapped_column(Integer)
    final: Mapped[bool] = mapped_column()
    confidence: Mapped[float | None] = mapped_column(Float)
    first_timestamp: Mapped[float] = mapped_column(Float)
    last_timestamp: Mapped[float] = mapped_column(Float)
    n_detections: Mapped[int] = mapped_column(Integer)
    detections_json: Mapped[str] = mapped_column(Text)
    published_at: Mapped[datetime] = mapped_column(default=utcnow)


class LiveSettledDetection(Base):
    """A detection the live association is done with: in a published vehicle (`vehicle_seq`),
    or left unassigned or late (NULL). Later windows leave these out."""

    __tablename__ = "live_settled_detection"
    __table_args__ = (
        Index("ix_live_settled_detection_deployment_id_timestamp", "deployment_id", "timestamp"),
    )

    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE"), primary_key=True
    )
    batch_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("batch.id", ondelete="CASCADE"), primary_key=True
    )
    row: Mapped[int] = mapped_column(Integer, primary_key=True)
    timestamp: Mapped[float] = mapped_column(Float)
    vehicle_seq: Mapped[int | None] = mapped_column(DetectionKey)
    late: Mapped[bool] = mapped_column(default=False)


class Webhook(Base):
    """An HTTPS endpoint of a deployment's that receives its events (`event_types`), signed with
    `secret` (kept in clear: the service signs with it; shown to the caller once, at creation)."""

    __tablename__ = "webhook"

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    deployment_id: Mapped[uuid.UUID] = mapped_column(
        ForeignKey("deployment.id", ondelete="CASCADE"), index=True
    )
    url: Mapped[str] = mapped_column(String(2000))
    secret: Mapped[str] = mapped_column(String(100))
    # The event types it receives, e.g. ["job.finished"].
    event_types: Mapped[list[str]] = mapped_column(JSON)
    description: Mapped[str | None] = mapped_column(String(200))
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class WebhookDelivery(Base):
    """One event to send to one webhook: the outbox row, written in the transaction that made
    the event happen, and then its delivery log (attempts, last answer, state)."""

    __tablename__ = "webhook_delivery"
    __table_args__ = (
        # The dispatcher's query: the pending deliveries that are due.
        Index("ix_webhook_delivery_state_next_attempt_at", "state", "next_attempt_at"),
        # The delivery log of a webhook, newest first.
        Index("ix_webhook_delivery_webhook_id_created_at", "webhook_id", "created_at"),
    )

    id: Mapped[uuid.UUID] = mapped_column(primary_key=True, default=uuid.uuid4)
    webhook_id: Mapped[uuid.UUID] = mapped_column(ForeignKey("webhook.id", ondelete="CASCADE"))
    # The event's id: the same in every delivery of one event (redeliveries included), so that
    # receivers can drop duplicates (delivery is at least once).
    event_id: Mapped[uuid.UUID] = mapped_column()
    event_type: Mapped[str] = mapped_column(String(100))
    # The request body, exactly as signed and sent.
    payload: Mapped[str] = mapped_column(Text)
    state: Mapped[str] = mapped_column(String(20))  # pending | delivered | failed
    attempts: Mapped[int] = mapped_column(Integer, default=0)
    next_attempt_at: Mapped[datetime | None] = mapped_column()
    last_attempt_at: Mapped[datetime | None] = mapped_column()
    last_status_code: Mapped[int | None] = mapped_column(Integer)
    last_error: Mapped[str | None] = mapped_column(Text)
    delivered_at: Mapped[datetime | None] = mapped_column()
    # The delivery this one sends again (POST .../redeliver), if it is a redelivery.
    redelivery_of: Mapped[uuid.UUID | None] = mapped_column()
    created_at: Mapped[datetime] = mapped_column(default=utcnow)


class WorkerHeartbeat(Base):
    """A worker process's last sign of life, on whichever host it runs: written at its
    heartbeat, read by the API's /metrics (`db/worker_heartbeats.py`)."""

    __tablename__ = "worker_heartbeat"

    worker_id: Mapped[str] = mapped_column(String(200), primary_key=True)
    host: Mapped[str] = mapped_column(String(255))
    pid: Mapped[int] = mapped_column(Integer)
    started_at: Mapped[datetime] = mapped_column()
    beat_at: Mapped[datetime] = mapped_column()
