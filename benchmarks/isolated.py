"""Run one method on one cached data set in a child process, under a time limit.

A child of its own per (method, size) makes peak memory honest: it is the high-water mark of
the child's resident set (VmHWM in /proc/PID/status), untouched by what the parent or earlier
runs allocated. Not `getrusage` of the child: on Linux its ru_maxrss also counts the parent's
resident set at the fork that preceded the exec, so every child would seem as large as the
parent. The child reports each step as a JSON line on stdout, so the parent can stop a run that
exceeds its time limit as soon as it does, and keep the repeats finished before it.

Child protocol (`python -m benchmarks.isolated SPEC_JSON`), one JSON object per line:
  {"event": "loaded", "peak_rss_kib": ..., "n": ...}   data loaded, imports done
  {"event": "grouped", "seconds": ..., "peak_rss_kib": ...}   one timed repeat
  {"event": "scored", "accuracy": ...}                  the first repeat's accuracy
"""

from __future__ import annotations

import json
import os
import queue
import resource
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

Outcome = Literal["ok", "timeout", "error"]

# Python start-up, imports and loading 10^6 detections take a few seconds; be generous.
LOAD_ALLOWANCE_SECONDS = 120.0
# Scoring is not what is measured, but at 10^6 detections it takes seconds.
SCORE_ALLOWANCE_SECONDS = 300.0


@dataclass(frozen=True)
class RunSpec:
    """What the child runs: `method` on the detections cached at `dataset`, `repeats` times.

    After `min_repeats`, the child stops early once the repeats so far took `budget_seconds`.
    """

    method: str
    dataset: str
    repeats: int
    min_repeats: int
    budget_seconds: float


@dataclass
class IsolatedRun:
    """What the parent saw: timed repeats, accuracy, peak memory, and how the child ended."""

    outcome: Outcome = "ok"
    seconds: list[float] = field(default_factory=list)
    accuracy: float | None = None
    n_detections: int | None = None
    baseline_rss_mib: float | None = None
    peak_rss_mib: float | None = None
    error: str | None = None


def run_isolated(spec: RunSpec, time_limit: float) -> IsolatedRun:
    """Run `spec` in a child; a repeat taking longer than `time_limit` seconds ends it."""
    result = IsolatedRun()
    with tempfile.TemporaryFile(mode="w+") as stderr:
        child = subprocess.Popen(
            [sys.executable, "-m", "benchmarks.isolated", json.dumps(spec.__dict__)],
            stdout=subprocess.PIPE,
            stderr=stderr,
            text=True,
            cwd=Path(__file__).resolve().parent.parent,
        )
        assert child.stdout is not None
        lines: queue.Queue[str | None] = queue.Queue()
        reader = threading.Thread(target=_pump, args=(child.stdout, lines), daemon=True)
        reader.start()
        deadline = time.monotonic() + LOAD_ALLOWANCE_SECONDS
        while True:
            try:
                line = lines.get(timeout=max(0.0, deadline - time.monotonic()))
            except queue.Empty:
                # Its peak so far is still readable; then stop it (only the child we started).
                peak = peak_rss_kib(child.pid)
                if peak is not None:
                    result.peak_rss_mib = peak / 1024
                os.kill(child.pid, signal.SIGKILL)
                result.outcome = "timeout"
                break
            if line is None:  # the child closed stdout: it has finished or died
                break
            event = json.loads(line)
            if event["event"] == "loaded":
                result.n_detections = event["n"]
                result.baseline_rss_mib = result.peak_rss_mib = event["peak_rss_kib"] / 1024
                deadline = time.monotonic() + time_limit
            elif event["event"] == "grouped":
                result.seconds.append(event["seconds"])
                result.peak_rss_mib = event["peak_rss_kib"] / 1024
                allowance = SCORE_ALLOWANCE_SECONDS if result.accuracy is None else 0.0
                deadline = time.monotonic() + allowance + time_limit
            elif event["event"] == "scored":
                result.accuracy = event["accuracy"]
                deadline = time.monotonic() + time_limit
        child.wait()
        reader.join()
        if result.outcome == "ok" and child.returncode != 0:
            stderr.seek(0)
            last_lines = stderr.read().strip().splitlines()
            result.outcome = "error"
            result.error = last_lines[-1] if last_lines else f"exit status {child.returncode}"
    return result


def _pump(stream: Any, lines: queue.Queue[str | None]) -> None:
    for line in stream:
        lines.put(line)
    lines.put(None)


def _child(spec: RunSpec) -> None:
    from benchmarks.datasets import load_detections
    from benchmarks.methods import grouping_method
    from roadlink.association.scores import score_grouping

    detections = load_detections(Path(spec.dataset))
    group = grouping_method(spec.method)
    _emit(event="loaded", n=len(detections), peak_rss_kib=peak_rss_kib())
    spent = 0.0
    for repeat in range(spec.repeats):
        start = time.perf_counter()
        groups = group(detections)
        seconds = time.perf_counter() - start
        _emit(event="grouped", seconds=seconds, peak_rss_kib=peak_rss_kib())
        if repeat == 0:
            # The methods are deterministic (seeded), so one score stands for every repeat.
            metrics = score_grouping(groups, detections.target)
            _emit(event="scored", accuracy=None if metrics is None else metrics.accuracy)
        del groups
        spent += seconds
        if repeat + 1 >= spec.min_repeats and spent >= spec.budget_seconds:
            break


def peak_rss_kib(pid: int | None = None) -> int | None:
    """Peak resident set (KiB) of a process since its exec; None if it has already exited.

    Read from /proc (Linux). Elsewhere, for this process only, `getrusage`'s ru_maxrss, which
    may include the parent's resident set at fork.
    """
    status = Path(f"/proc/{pid or 'self'}/status")
    try:
        for line in status.read_text().splitlines():
            if line.startswith("VmHWM:"):
                return int(line.split()[1])
    except OSError:
        pass
    if pid is None:
        return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return None


def _emit(**event: Any) -> None:
    print(json.dumps(event), flush=True)


if __name__ == "__main__":
    _child(RunSpec(**json.loads(sys.argv[1])))
