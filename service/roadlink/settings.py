"""Service configuration, read only from ROADLINK_* environment variables.

The defaults run on a laptop with nothing else installed: an SQLite file in the working directory,
the API on 127.0.0.1:8000 and one worker per core.
"""

from __future__ import annotations

import os
import tempfile
from typing import Literal

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict


def _cores() -> int:
    return max(1, len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else 1)


def _heartbeat_dir() -> str:
    # Per user, so that one user's workers never vouch for another's on a shared host.
    return os.path.join(tempfile.gettempdir(), f"roadlink-workers-{os.getuid()}")


class Settings(BaseSettings):
    """Everything the API and the workers can be told; each field is ROADLINK_<NAME>."""

    model_config = SettingsConfigDict(env_prefix="ROADLINK_", extra="ignore", frozen=True)

    database_url: str = Field(
        default="sqlite:///./roadlink.db",
        description="SQLAlchemy URL. sqlite:///path (embedded default) or "
        "postgresql+psycopg://user:password@host:port/database.",
    )
    sqlite_synchronous: Literal["full", "normal"] = Field(
        default="normal",
        description="SQLite only: `full` syncs every commit to disk (a committed batch survives "
        "a power loss); `normal` (WAL) syncs at checkpoints only: as safe against a crash of "
        "roadlink or its processes, but a power loss or an operating-system crash may lose the "
        "last commits (never half of one). See docs/deploy.md.",
    )
    host: str = Field(default="127.0.0.1", description="Address the API listens on.")
    port: int = Field(default=8000, ge=0, le=65535, description="Port the API listens on.")
    workers: int = Field(
        default_factory=_cores,
        ge=0,
        description="Worker processes `roadlink serve` starts (0 = API only).",
        json_schema_extra={"shown_default": "the number of cores"},
    )
    worker_niceness: int = Field(
        default=0,
        ge=0,
        le=19,
        description="How much lower than their parent's the CPU priority of the worker "
        "processes `serve` (or `worker` with several) starts is: added to their nice value (0 "
        "= the same, 19 = the lowest). Raise it (10, say) where association must never slow "
        "the API's answers on cores they share; it also puts every job behind any other work "
        "on the host. See docs/deploy.md.",
    )
    lease_seconds: float = Field(
        default=30.0,
        gt=0,
        description="How long a claimed job stays a worker's without a heartbeat before it is "
        "rescued and run again.",
    )
    heartbeat_seconds: float = Field(
        default=2.0, gt=0, description="How often a worker renews its lease and reports progress."
    )
    poll_seconds: float = Field(
        default=0.25,
        gt=0,
        description="How often an idle worker looks for work when no notification wakes it.",
    )
    max_attempts: int = Field(
        default=3,
        ge=1,
        description="Runs a job gets (a dead worker or associator process, or a lost lease, "
        "uses one) before it fails.",
    )
    retry_backoff_seconds: float = Field(
        default=1.0,
        ge=0,
        description="Delay before such a job is run again (doubles per attempt).",
    )
    job_timeout_seconds: float = Field(
        default=600.0,
        gt=0,
        description="Longest a job's association may run (counted from when its associator "
        "process has the job): past it the job fails and that process is killed, freeing the "
        "worker for the next job.",
    )
    max_body_bytes: int = Field(
        default=64 * 1024 * 1024, gt=0, description="Largest request body accepted (413 beyond)."
    )
    max_wait_seconds: float = Field(
        default=60.0, ge=0, description="Longest `?wait=` a result request may ask for."
    )
    keep_alive_seconds: int = Field(
        default=75,
        ge=1,
        description="How long the API keeps an idle HTTP connection open. Longer than the "
        "idle expiry of clients' connection pools (httpx: 5 s) and of load balancers in front "
        "(commonly 60 s): when both sides time out together, a request sent on a connection "
        "the server is closing is lost.",
    )
    log_level: str = Field(default="info", description="Log level of the API and the workers.")
    log_format: Literal["text", "json"] = Field(
        default="text",
        description="`text`: a line of words per record. `json`: one JSON object per line "
        "(timestamp, level, logger, message, and the request, deployment, batch and job ids "
        "that apply), from the API, its access log and the workers alike.",
    )
    stall_log_ms: float = Field(
        default=100.0,
        ge=0,
        description="The API logs, as a warning with its cause, each garbage collection and each "
        "delay of its event loop at least this long (0 = none); all are in /metrics.",
    )
    auth: Literal["required", "disabled"] = Field(
        default="required",
        description="`required`: every /v1 request needs an API key (`Authorization: Bearer`). "
        "`disabled` is for local development only; `serve` refuses it on a non-loopback host.",
    )
    rate_limit_per_second: float = Field(
        default=20.0,
        ge=0,
        description="Requests per second each API key may sustain, per API replica (0 = no limit).",
    )
    rate_limit_burst: int = Field(
        default=100,
        ge=1,
        description="Requests an API key may send at once before the rate "
        "limit applies (the token bucket's size).",
    )
    max_batch_detections: int = Field(
        default=1_000_000, gt=0, description="Most detections one batch may hold (422 beyond)."
    )
    max_view_detections: int = Field(
        default=50_000,
        gt=0,
        description="Largest job (in detections) whose result the API draws or localises: the "
        "plot, positions and targets routes and the job page's plot and tables. Larger jobs are "
        "413 there (the page says so); their result is read whole from GET /v1/jobs/{id}/result.",
    )
    public_url: str | None = Field(
        default=None,
        pattern=r"^https?://[^\s/?#]+(/[^\s?#]*)?$",
        description="The service's address as its users reach it (e.g. https://roadlink.example; "
        "behind a proxy, the proxy's), for the links it hands out. Unset, links are relative "
        "to the server the client asked. Never taken from the request's Host header.",
    )
    worker_heartbeat_dir: str = Field(
        default_factory=_heartbeat_dir,
        description="Where each worker process touches a file as it runs, so that "
        "`roadlink worker --check` (a container's health check) can tell it is alive.",
        json_schema_extra={
            "shown_default": "roadlink-workers-<uid> in the system's temporary directory"
        },
    )
    idempotency_hours: float = Field(
        default=24.0,
        ge=24.0,
        description="How long an Idempotency-Key is remembered (at least 24 hours).",
    )
    webhook_max_attempts: int = Field(
        default=10,
        ge=1,
        description="Attempts a webhook delivery gets (an answer other than 2xx, or none, "
        "spends one) before it is marked failed; it can still be redelivered by hand.",
    )
    webhook_backoff_seconds: float = Field(
        default=10.0,
        ge=0,
        description="Delay before a webhook delivery's second attempt; it doubles per attempt, "
        "up to ROADLINK_WEBHOOK_MAX_BACKOFF_SECONDS.",
    )
    webhook_max_backoff_seconds: float = Field(
        default=3600.0, ge=0, description="Longest delay between two attempts of a delivery."
    )
    webhook_timeout_seconds: float = Field(
        default=10.0,
        gt=0,
        description="How long a worker waits for a webhook's receiver to answer one attempt.",
    )
    webhook_allow_http: bool = Field(
        default=False,
        description="Accept plain http:// webhook URLs to any host. Off, a webhook must be "
        "https://, or http:// to a loopback address (development and tests).",
    )
    retention_days: float | None = Field(
        default=None,
        gt=0,
        description="Delete batches (with their detections), finished jobs (with their results) "
        "and webhook deliveries older than this many days, in the workers, hourly. Unset: keep "
        "everything until deleted through the API.",
    )

    @field_validator("retention_days", mode="before")
    @classmethod
    def _empty_retention_is_unset(cls, value: object) -> object:
        return None if value == "" else value

    @field_validator("public_url", mode="before")
    @classmethod
    def _empty_is_unset(cls, value: object) -> object:
        return None if value == "" else value

    @model_validator(mode="after")
    def _heartbeat_within_lease(self) -> Settings:
        if self.heartbeat_seconds >= self.lease_seconds:
            raise ValueError(
                "ROADLINK_HEARTBEAT_SECONDS must be shorter than ROADLINK_LEASE_SECONDS, "
                "or every running job would lose its lease"
            )
        return self
