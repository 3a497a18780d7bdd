"""The benchmark sections, in the order they run. See benchmarks/README.md to add one."""

from __future__ import annotations

from collections.abc import Callable

from benchmarks.report import Section
from benchmarks.sections import (
    associators,
    files,
    ingest,
    latency,
    overhead,
    peer,
    throughput,
)

SectionRunner = Callable[[bool], Section]

SECTIONS: dict[str, SectionRunner] = {
    associators.NAME: associators.run,
    peer.NAME: peer.run,
    ingest.NAME: ingest.run,
    latency.NAME: latency.run,
    throughput.NAME: throughput.run,
    overhead.NAME: overhead.run,
    files.NAME: files.run,
    files.READ_NAME: files.run_read,
}
