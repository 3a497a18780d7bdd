"""What keeps the API's event loop from answering: its lateness and the garbage collections.

One thread, the event loop's, answers /healthz and runs every async route, so whatever keeps it
from running delays every answer: CPU-bound work on the loop, a garbage collection (which stops
every thread), request threads holding the GIL, or the OS giving the cores to other processes.
Two cheap watches tell these apart:

- a task on the loop asks to wake every `LAG_INTERVAL_SECONDS` and measures how late it woke.
  Over the same span it reads the loop thread's CPU time, the rest of the process's, the time the
  loop thread waited for a core (Linux's schedstat; absent elsewhere) and the collections' time,
  so a late wake says its cause: the loop was busy, other threads held the GIL, a collection ran,
  or no core was free;
- `gc.callbacks` time each collection, whichever thread triggers it.

Both feed Prometheus histograms (`roadlink_event_loop_lag_seconds`, `roadlink_gc_pause_seconds`
by generation), and each one at least ROADLINK_STALL_LOG_MS long is logged as a warning. Their
cost is a wake-up of the loop every 50 ms and a clock read per collection.
"""

from __future__ import annotations

import asyncio
import contextlib
import gc
import logging
import time
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path

from prometheus_client import CollectorRegistry, Histogram

from roadlink.api.tasks import in_background

log = logging.getLogger("roadlink.stalls")

LAG_INTERVAL_SECONDS = 0.05
STALL_BUCKETS = (0.001, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5)
_SCHEDSTAT = Path("/proc/thread-self/schedstat")


@dataclass(frozen=True)
class Clocks:
    """The clocks a late wake is read against, at one instant, in seconds."""

    loop_cpu: float
    process_cpu: float
    core_wait: float | None
    gc: float

    def since(self, earlier: Clocks) -> Clocks:
        wait = None
        if self.core_wait is not None and earlier.core_wait is not None:
            wait = self.core_wait - earlier.core_wait
        return Clocks(
            loop_cpu=self.loop_cpu - earlier.loop_cpu,
            process_cpu=self.process_cpu - earlier.process_cpu,
            core_wait=wait,
            gc=self.gc - earlier.gc,
        )


def core_wait() -> float | None:
    """Seconds the calling thread has waited, runnable, for a core (None off Linux)."""
    try:
        return int(_SCHEDSTAT.read_text().split()[1]) / 1e9
    except (OSError, IndexError, ValueError):
        return None


def lag_message(late: float, span: float, spent: Clocks) -> str:
    """A late wake of the loop and where the time of its span went, in one line."""
    others = max(spent.process_cpu - spent.loop_cpu, 0.0)
    wait = "unknown" if spent.core_wait is None else f"{spent.core_wait * 1000:.0f} ms"
    return (
        f"event loop {late * 1000:.0f} ms late; of the {span * 1000:.0f} ms since its previous "
        f"wake: loop thread on a core {spent.loop_cpu * 1000:.0f} ms, waiting for a core {wait}, "
        f"other threads on a core {others * 1000:.0f} ms, garbage collection "
        f"{spent.gc * 1000:.0f} ms"
    )


class StallWatch:
    """The two watches of one app (see the module's docstring); `running` switches them on."""

    def __init__(self, registry: CollectorRegistry, log_seconds: float) -> None:
        self.log_seconds = log_seconds
        self.gc_seconds = 0.0
        self._gc_started = self._gc_cpu_started = 0.0
        self._collecting = False
        self.lag = Histogram(
            "roadlink_event_loop_lag_seconds",
            f"How late the API's event loop wakes a task that asks every {LAG_INTERVAL_SECONDS} s.",
            buckets=STALL_BUCKETS,
            registry=registry,
        )
        self.gc_pause = Histogram(
            "roadlink_gc_pause_seconds",
            "Garbage collections of the API process (every thread stops meanwhile).",
            ["generation"],
            buckets=STALL_BUCKETS,
            registry=registry,
        )

    def clocks(self) -> Clocks:
        """Now, read from the loop's thread. A collection's finalizers can let the loop run
        before the collection ends, so one in progress counts up to now."""
        collecting = time.perf_counter() - self._gc_started if self._collecting else 0.0
        gc_seconds = self.gc_seconds + collecting
        return Clocks(time.thread_time(), time.process_time(), core_wait(), gc_seconds)

    def on_gc(self, phase: str, info: dict[str, int]) -> None:
        """A `gc.callbacks` entry: times the collection between its start and its stop."""
        now, cpu = time.perf_counter(), time.thread_time()
        self._collecting = phase == "start"
        if self._collecting:
            self._gc_started, self._gc_cpu_started = now, cpu
            return
        pause = now - self._gc_started
        self.gc_seconds += pause
        self.gc_pause.labels(str(info["generation"])).observe(pause)
        if self.log_seconds and pause >= self.log_seconds:
            # Counting the generation's objects walks it: only for the few collections logged.
            log.warning(
                "garbage collection of generation %d took %.0f ms (on a core %.0f ms) over %d "
                "objects, %d collected",
                info["generation"],
                pause * 1000,
                (cpu - self._gc_cpu_started) * 1000,
                len(gc.get_objects(info["generation"])),
                info["collected"],
            )

    def observe_lag(self, late: float, span: float, spent: Clocks) -> None:
        self.lag.observe(late)
        if self.log_seconds and late >= self.log_seconds:
            log.warning("%s", lag_message(late, span, spent))

    async def sample_lag(self) -> None:
        """Forever: sleep `LAG_INTERVAL_SECONDS` on the loop, observe how late the wake was."""
        loop = asyncio.get_running_loop()
        woke, clocks = loop.time(), self.clocks()
        while True:
            await asyncio.sleep(LAG_INTERVAL_SECONDS)
            now, later = loop.time(), self.clocks()
            late = max(now - woke - LAG_INTERVAL_SECONDS, 0.0)
            self.observe_lag(late, now - woke, later.since(clocks))
            woke, clocks = now, later

    @contextlib.asynccontextmanager
    async def running(self) -> AsyncIterator[None]:
        """Both watches on while the context lasts (an app's lifespan)."""
        gc.callbacks.append(self.on_gc)
        try:
            async with in_background(self.sample_lag()):
                yield
        finally:
            gc.callbacks.remove(self.on_gc)
