"""The schema's enumerations, importable without SQLAlchemy (the CLI's start)."""

from __future__ import annotations

import subprocess
import sys

from roadlink.db import models
from roadlink.db.enums import ApiKeyScope, JobState


def test_only_succeeded_failed_and_cancelled_jobs_are_finished() -> None:
    finished = {state for state in JobState if state.finished}
    assert finished == {JobState.SUCCEEDED, JobState.FAILED, JobState.CANCELLED}


def test_the_schema_uses_these_very_enumerations() -> None:
    assert models.JobState is JobState
    assert models.ApiKeyScope is ApiKeyScope


def test_the_cli_starts_without_sqlalchemy_and_scikit_learn() -> None:
    """`roadlink associate` imports neither: the database's commands and the associators that
    need scikit-learn import them when they run."""
    script = (
        "import sys\n"
        "import roadlink.cli\n"
        "print(sorted(m for m in ('sqlalchemy', 'sklearn') if m in sys.modules))\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == "[]"
