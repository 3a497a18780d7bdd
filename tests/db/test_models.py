"""The schema's own column types: UTC timestamps on every database, a job's state as text
(`roadlink.db.models`)."""

from __future__ import annotations

from datetime import UTC, datetime, timedelta, timezone

import pytest
from sqlalchemy.dialects import postgresql, sqlite

from roadlink.db.models import JobState, JobStateType, UTCDateTime


def test_timestamps_are_stored_as_utc_and_read_back_aware() -> None:
    column = UTCDateTime()
    paris = datetime(2026, 1, 1, 13, 0, tzinfo=timezone(timedelta(hours=1)))
    on_sqlite = column.process_bind_param(paris, sqlite.dialect())
    assert on_sqlite == datetime(2026, 1, 1, 12, 0)  # naive UTC: SQLite has no time zones
    assert column.process_result_value(on_sqlite, sqlite.dialect()) == paris
    on_postgres = column.process_bind_param(paris, postgresql.dialect())
    assert on_postgres == datetime(2026, 1, 1, 12, 0, tzinfo=UTC)


def test_a_naive_timestamp_is_refused() -> None:
    with pytest.raises(ValueError, match="naive"):
        UTCDateTime().process_bind_param(datetime(2026, 1, 1), sqlite.dialect())


def test_a_jobs_state_is_its_text_and_nothing_else() -> None:
    column = JobStateType()
    assert column.process_bind_param(JobState.RUNNING, sqlite.dialect()) == "running"
    assert column.process_result_value("succeeded", sqlite.dialect()) is JobState.SUCCEEDED
    with pytest.raises(ValueError):
        column.process_bind_param("paused", sqlite.dialect())
    assert JobState.CANCELLED.finished and not JobState.QUEUED.finished
