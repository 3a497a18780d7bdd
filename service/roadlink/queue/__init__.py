"""The job queue on the database, and the worker loop that drains it."""

from roadlink.queue.transitions import (
    ClaimedJob,
    cancel_job,
    claim_next_job,
    complete_job,
    enqueue_job,
    fail_job,
    heartbeat_job,
    release_job,
    rescue_expired_jobs,
)

__all__ = [
    "ClaimedJob",
    "cancel_job",
    "claim_next_job",
    "complete_job",
    "enqueue_job",
    "fail_job",
    "heartbeat_job",
    "release_job",
    "rescue_expired_jobs",
]
