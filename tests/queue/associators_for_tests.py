"""Associators that exist only in tests: one that takes its time (reporting progress or not) and
records each run it completes, and one that crashes. Registered with `register()` in the process
whose workers must know them (worker children are forked, so they inherit the registry)."""

from __future__ import annotations

import os
import time

import numpy as np
from pydantic import Field

from roadlink.association.associators import ASSOCIATORS, Associator, AssociatorParams, Progress
from roadlink.association.detections import Detections, IntArray


class SleepingParams(AssociatorParams):
    seconds: float = Field(default=0.0, ge=0, description="How long a run takes.")
    report_progress: bool = Field(
        default=True, description="Report progress every 10 ms (False: a stuck associator)."
    )
    log: str | None = Field(
        default=None, description="File a line '<tag> <pid>' is appended to per completed run."
    )
    tag: str = Field(default="", description="What the run writes to the log.")


class SleepingAssociator(Associator):
    """Sleeps, then leaves every detection unassigned."""

    name = "test-sleeping"
    description = "Sleeps for `seconds` (test only)."
    Params = SleepingParams

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        params = self.params
        assert isinstance(params, SleepingParams)
        end = time.monotonic() + params.seconds
        while (left := end - time.monotonic()) > 0:
            if params.report_progress and progress is not None:
                progress(1 - left / params.seconds)
                time.sleep(min(left, 0.01))
            else:
                time.sleep(left)
        if params.log is not None:
            # One short O_APPEND write per run: lines from concurrent processes never interleave.
            fd = os.open(params.log, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
            try:
                os.write(fd, f"{params.tag} {os.getpid()}\n".encode())
            finally:
                os.close(fd)
        return np.full(len(detections), -1, dtype=np.int64)


class CrashingParams(AssociatorParams):
    pass


class CrashingAssociator(Associator):
    """Raises as a bug would."""

    name = "test-crashing"
    description = "Raises RuntimeError (test only)."
    Params = CrashingParams

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        raise RuntimeError("out of memory")


def register() -> None:
    """Add the test associators to the registry of this process."""
    for cls in (SleepingAssociator, CrashingAssociator):
        ASSOCIATORS[cls.name] = cls
