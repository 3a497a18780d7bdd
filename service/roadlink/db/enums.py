"""The schema's enumerations, apart from it: the CLI names job states and key scopes without
importing SQLAlchemy (most of a second of every `roadlink` command's start). `models` uses
them, and they are importable from there too."""

from __future__ import annotations

import enum


class JobState(enum.StrEnum):
    """Where a job is in its life: queued -> running -> succeeded | failed | cancelled."""

    QUEUED = "queued"
    RUNNING = "running"
    SUCCEEDED = "succeeded"
    FAILED = "failed"
    CANCELLED = "cancelled"

    @property
    def finished(self) -> bool:
        return self in (JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED)


class ApiKeyScope(enum.StrEnum):
    """What an API key may do: `ingest` posts batches to the deployments it names, `read` reads
    everything and runs jobs, `admin` does all that and manages deployments and keys."""

    INGEST = "ingest"
    READ = "read"
    ADMIN = "admin"
