"""Soak on loopback: many clients mix everything a gateway and an analyst do, for minutes, while a
probe checks that the API keeps answering `/healthz` quickly and never answers 5xx.

    .venv/bin/python -m benchmarks.soak                         # 16 clients for 180 s
    .venv/bin/python -m benchmarks.soak --clients 16 --seconds 20 --json

A fresh `roadlink serve` (SQLite, 2 workers, authentication on, rate limits raised so that the
mix, not the limiter, is measured) gets, from each client in turn:
- a JSON or a CSV batch with an `Idempotency-Key`, and now and then the same post again at once
  from two threads (a gateway retrying while its first try is in flight);
- a job over the batches it posted, also under an `Idempotency-Key`, posted twice;
- `GET /v1/jobs/{id}/result?wait=S`, the result as CSV, its plot and positions.
A probe, in a process of its own, requests `/healthz` every 0.2 s throughout. Reports the status
counts, every 5xx and transport error, and the probe's latency percentiles; exits 1 when any
answer was 5xx or lost, or when the probe's slowest answer exceeded `--healthz-limit` seconds.

The clients' threads, the load generator, run in a process of their own at `LOAD_NICENESS`, a
lower priority than the server's: real clients are on other machines, and on a development
machine's two cores a load generator at the server's priority measured its own competition for
the cores, not the service. Only the load generator is lowered: the API process and the probe
keep their priority, so a stall of the API's own making still shows. (The server's workers and
plot renderer run at a lower priority of the server's own choosing, as in production.) The
report gives the CPU seconds of each, and of the machine as a whole: the machine may be shared.

The server logs each stall of its event loop and each garbage collection of at least
`STALL_LOG_MS` (ROADLINK_STALL_LOG_MS, see roadlink/api/stalls.py); every probe slower than
`--healthz-limit` is reported with the stalls logged while it waited, which say what it waited
for.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing
import multiprocessing.queues
import os
import random
import re
import shutil
import sys
import tempfile
import threading
import time
import uuid
from collections import Counter
from dataclasses import dataclass, field
from datetime import datetime
from pathlib import Path

import httpx
import numpy as np

from roadlink.api.stalls import core_wait
from roadlink.association.csvio import write_detections_csv
from roadlink.simulation import preset, simulate
from tests.live_server import LiveServer, free_port, roadlink, sqlite_env

PROBE_INTERVAL = 0.2
LOAD_NICENESS = 10
STALL_LOG_MS = 20
# A stall is logged when it ends, up to a lag sample's interval after the answer it delayed.
STALL_WINDOW_SECONDS = 0.1
_STALL_LINE = re.compile(r"^(\S+ \S+) WARNING ((?:event loop|garbage collection).*)$")


@dataclass
class Tally:
    """What the clients and the probe saw; shared by their threads."""

    statuses: Counter[str] = field(default_factory=Counter)
    failures: list[str] = field(default_factory=list)
    probe_seconds: list[float] = field(default_factory=list)
    slow_probes: list[tuple[float, float, float]] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)

    def record(self, what: str, answer: httpx.Response | None, error: str = "") -> None:
        with self.lock:
            if answer is None:
                self.statuses[f"{what} lost"] += 1
                self.failures.append(f"{what}: {error}")
                return
            self.statuses[f"{what} {answer.status_code}"] += 1
            if answer.status_code >= 500:
                self.failures.append(f"{what}: {answer.status_code} {answer.text[:300]}")


def _bodies(seed: int) -> tuple[list[dict[str, object]], str]:
    """One paper-size batch as JSON rows and as CSV, with detection ids unique to `seed`."""
    detections = simulate(preset("large"), seed=seed).detections
    csv_text = write_detections_csv(detections)
    rows = [
        {
            "position": float(p),
            "velocity": float(v),
            "timestamp": float(t),
            "sensor_id": str(s),
        }
        for p, v, t, s in zip(
            detections.position,
            detections.velocity,
            detections.timestamp,
            detections.sensor_id,
            strict=True,
        )
    ]
    return rows, csv_text


def _call(tally: Tally, what: str, http: httpx.Client, method: str, path: str, **kw: object):
    try:
        answer = http.request(method, path, **kw)  # type: ignore[arg-type]
    except httpx.HTTPError as exc:
        tally.record(what, None, repr(exc))
        return None
    tally.record(what, answer)
    return answer


def _twice_at_once(
    tally: Tally, what: str, http: httpx.Client, path: str, **kw: object
) -> list[httpx.Response]:
    """The same post from two threads at once, as a retrying gateway sends it."""
    answers: list[httpx.Response] = []
    barrier = threading.Barrier(2)

    def post() -> None:
        barrier.wait()
        answer = _call(tally, what, http, "POST", path, **kw)
        if answer is not None:
            answers.append(answer)

    threads = [threading.Thread(target=post) for _ in range(2)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    return answers


def _client(
    k: int, url: str, key: str, deployment: str, stop_at: float, wait: float, tally: Tally
) -> None:
    rng = random.Random(k)
    headers = {"Authorization": f"Bearer {key}"}
    with httpx.Client(base_url=url, headers=headers, timeout=wait + 60) as http:
        n = 0
        while time.monotonic() < stop_at:
            rows, csv_text = _bodies(seed=1000 * k + n)
            n += 1
            batch_path = f"/v1/deployments/{deployment}/batches"
            retry = {"Idempotency-Key": uuid.uuid4().hex}
            if rng.random() < 0.5:
                answers = _twice_at_once(
                    tally, "batch json", http, batch_path, json={"detections": rows}, headers=retry
                )
            else:
                answers = _twice_at_once(
                    tally,
                    "batch csv",
                    http,
                    batch_path,
                    content=csv_text,
                    headers={**retry, "content-type": "text/csv"},
                )
            created = [a for a in answers if a.status_code in (200, 201)]
            if not created:
                continue
            batch = created[0].json()["id"]
            job_body = {"batch_id": batch, "associator": "assignment"}
            answers = _twice_at_once(
                tally,
                "job",
                http,
                "/v1/jobs",
                json=job_body,
                headers={"Idempotency-Key": uuid.uuid4().hex},
            )
            jobs = [a for a in answers if a.status_code in (200, 202)]
            if not jobs:
                continue
            job = jobs[0].json()["id"]
            _call(
                tally, "result wait", http, "GET", f"/v1/jobs/{job}/result", params={"wait": wait}
            )
            _call(
                tally, "result csv", http, "GET", f"/v1/jobs/{job}/result", params={"format": "csv"}
            )
            _call(tally, "plot", http, "GET", f"/v1/jobs/{job}/plot")
            _call(tally, "positions", http, "GET", f"/v1/jobs/{job}/positions", params={"t": 10})


def _generate_load(
    clients: int,
    url: str,
    key: str,
    deployment: str,
    stop_at: float,
    wait: float,
    results: multiprocessing.queues.Queue,
) -> None:
    """In a process of its own at LOAD_NICENESS (see the module's docstring): the clients'
    (status counts, failures, CPU seconds)."""
    os.nice(LOAD_NICENESS)
    tally = Tally()
    threads = [
        threading.Thread(target=_client, args=(k, url, key, deployment, stop_at, wait, tally))
        for k in range(clients)
    ]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    results.put((dict(tally.statuses), tally.failures, time.process_time()))


def _probe(url: str, stop_at: float, results: multiprocessing.queues.Queue) -> None:
    """In a process of its own, so that the clients' threads cannot delay its measurements:
    (status or error, wall-clock start, seconds, seconds the probe itself waited for a core) of a
    /healthz request every PROBE_INTERVAL until `stop_at` (time.monotonic(), which all
    processes share)."""
    answers: list[tuple[str, float, float, float]] = []
    with httpx.Client(base_url=url, timeout=30) as http:
        while time.monotonic() < stop_at:
            wall, began, waited = time.time(), time.perf_counter(), core_wait() or 0.0
            try:
                status = str(http.get("/healthz").status_code)
            except httpx.HTTPError as exc:
                status = repr(exc)
            elapsed = time.perf_counter() - began
            answers.append((status, wall, elapsed, (core_wait() or 0.0) - waited))
            time.sleep(PROBE_INTERVAL)
    results.put(answers)


def _record_probe(
    answers: list[tuple[str, float, float, float]], tally: Tally, limit: float
) -> None:
    for status, wall, seconds, waited in answers:
        if status.isdigit():
            tally.statuses[f"healthz {status}"] += 1
            tally.probe_seconds.append(seconds)
            if seconds > limit:
                tally.slow_probes.append((wall, seconds, waited))
            if int(status) >= 500:
                tally.failures.append(f"healthz: {status}")
        else:
            tally.statuses["healthz lost"] += 1
            tally.failures.append(f"healthz: {status}")


def _logged_stalls(log: Path) -> list[tuple[float, str]]:
    """(wall-clock time, message) of each stall the server logged."""
    stalls = []
    for line in log.read_text(errors="replace").splitlines():
        found = _STALL_LINE.match(line)
        if found:
            when = datetime.strptime(found[1], "%Y-%m-%d %H:%M:%S,%f").timestamp()
            stalls.append((when, found[2]))
    return stalls


def _explain(slow: list[tuple[float, float, float]], stalls: list[tuple[float, str]]) -> list[str]:
    """Each slow probe, how long the probe itself waited for a core, and the stalls the server
    logged while it waited (or that none were)."""
    lines = []
    for wall, seconds, waited in sorted(slow):
        during = [
            f"+{(when - wall) * 1000:.0f} ms: {message}"
            for when, message in stalls
            if wall <= when <= wall + seconds + STALL_WINDOW_SECONDS
        ]
        stamp = datetime.fromtimestamp(wall).strftime("%H:%M:%S.%f")[:-3]
        lines.append(
            f"{stamp} {seconds * 1000:.0f} ms (the probe waited {waited * 1000:.0f} ms for a "
            "core): " + (" | ".join(during) or "no stall")
        )
    return lines


def _stall_counts(stalls: list[tuple[float, str]]) -> dict[str, int]:
    """How many stalls of each kind the server logged, and how many of them were 100 ms or more."""
    counts: Counter[str] = Counter()
    for _, message in stalls:
        kind = "gc" if message.startswith("garbage") else "loop lag"
        counts[kind] += 1
        if int(re.search(r"(\d+) ms", message)[1]) >= 100:  # type: ignore[index]
            counts[f"{kind} >= 100 ms"] += 1
    return dict(sorted(counts.items()))


def _proc_stats() -> dict[int, tuple[int, int, float]]:
    """(parent pid, nice, CPU seconds) of every process, from Linux's /proc (empty elsewhere)."""
    ticks = os.sysconf("SC_CLK_TCK") if hasattr(os, "sysconf") else 100
    stats = {}
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except OSError:  # the process ended meanwhile
            continue
        # After the name: state, ppid, ... utime (12th), stime (13th), ..., nice (17th).
        cpu = (int(fields[11]) + int(fields[12])) / ticks
        stats[int(stat.parent.name)] = (int(fields[1]), int(fields[16]), cpu)
    return stats


def _load_average() -> list[float]:
    """The machine's load over the last 1, 5 and 15 minutes (it may be shared)."""
    return [round(load, 2) for load in os.getloadavg()]


def _machine_busy() -> float:
    """CPU seconds all cores have been busy since boot, from Linux's /proc/stat (0 elsewhere)."""
    try:
        fields = Path("/proc/stat").read_text().split("\n", 1)[0].split()[1:]
    except OSError:
        return 0.0
    ticks = [int(f) for f in fields[:8]]  # user, nice, system, idle, iowait, irq, softirq, steal
    return (sum(ticks) - ticks[3] - ticks[4]) / os.sysconf("SC_CLK_TCK")


def _server_cpu(pid: int) -> dict[str, float]:
    """CPU seconds of the server's process tree so far: the API process, its descendants at
    normal priority (the plot renderer) and those at a lower one (workers, associators)."""
    stats = _proc_stats()
    if pid not in stats:
        return {}
    cpu = {"api": stats[pid][2]}
    tree = {pid}
    for _ in range(3):  # workers' associator processes are the API's grandchildren
        tree |= {child for child, (parent, _, _) in stats.items() if parent in tree}
    for child in tree - {pid}:
        _, nice, seconds = stats[child]
        name = f"children at nice {nice}"
        cpu[name] = cpu.get(name, 0.0) + seconds
    return {name: round(seconds, 1) for name, seconds in sorted(cpu.items())}


def run_soak(
    clients: int, seconds: float, wait: float, healthz_limit: float = 0.1
) -> dict[str, object]:
    """Start a server, soak it; the figures (see the module's docstring). The server's files
    (database, log) are removed afterwards, and kept, saying where, when the soak fails."""
    directory = Path(tempfile.mkdtemp(prefix="roadlink-soak-"))
    try:
        figures = _soak(directory, clients, seconds, wait, healthz_limit)
    except BaseException:
        print(f"the soak failed; its server's files are kept in {directory}", file=sys.stderr)
        raise
    shutil.rmtree(directory, ignore_errors=True)
    return figures


def _soak(
    directory: Path, clients: int, seconds: float, wait: float, healthz_limit: float
) -> dict[str, object]:
    env = sqlite_env(
        directory,
        ROADLINK_RATE_LIMIT_PER_SECOND="10000",
        ROADLINK_RATE_LIMIT_BURST="10000",
        ROADLINK_STALL_LOG_MS=str(STALL_LOG_MS),
    )
    admin = roadlink("keys", "create", "--scope", "admin", env=env, cwd=directory).strip()
    server = LiveServer(directory, env, free_port())
    server.start(workers=2)
    tally = Tally()
    load_before = _load_average()
    try:
        with httpx.Client(
            base_url=server.url, headers={"Authorization": f"Bearer {admin}"}
        ) as http:
            answer = http.post("/v1/deployments", json={"name": "soak"})
            answer.raise_for_status()
            deployment = answer.json()["id"]
        spawn = multiprocessing.get_context("spawn")
        probed: multiprocessing.queues.Queue = spawn.Queue()
        loaded: multiprocessing.queues.Queue = spawn.Queue()
        stop_at = time.monotonic() + seconds
        prober = spawn.Process(target=_probe, args=(server.url, stop_at, probed))
        load = (clients, server.url, admin, deployment, stop_at, wait, loaded)
        generator = spawn.Process(target=_generate_load, args=load)
        busy = _machine_busy()
        prober.start()
        generator.start()
        statuses, failures, generator_cpu = loaded.get(timeout=seconds + 2 * wait + 300)
        tally.statuses.update(statuses)
        tally.failures.extend(failures)
        _record_probe(probed.get(timeout=seconds + 120), tally, healthz_limit)
        prober.join()
        generator.join()
        machine_cpu = _machine_busy() - busy
        server_cpu = _server_cpu(server.pid())
    finally:
        server.stop()
    probe = np.array(tally.probe_seconds) if tally.probe_seconds else np.array([np.nan])
    stalls = _logged_stalls(directory / "serve.log")
    return {
        "clients": clients,
        "seconds": seconds,
        "requests": sum(tally.statuses.values()),
        "statuses": dict(sorted(tally.statuses.items())),
        "failures": tally.failures[:20],
        "failure_count": len(tally.failures),
        "healthz_p50_ms": round(float(np.percentile(probe, 50)) * 1000, 1),
        "healthz_p99_ms": round(float(np.percentile(probe, 99)) * 1000, 1),
        "healthz_max_ms": round(float(probe.max()) * 1000, 1),
        "healthz_over_100ms": int((probe > 0.1).sum()),
        f"stalls_logged_over_{STALL_LOG_MS}ms": _stall_counts(stalls),
        "slow_probes": _explain(tally.slow_probes, stalls),
        "cpus": os.cpu_count(),
        "cpu_seconds": {
            **server_cpu,
            "load generator": round(generator_cpu, 1),
            "machine": round(machine_cpu, 1),
        },
        "load_average_before": load_before,
        "load_average_after": _load_average(),
    }


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--clients", type=int, default=16)
    parser.add_argument("--seconds", type=float, default=180.0)
    parser.add_argument("--wait", type=float, default=10.0, help="?wait= of the result requests")
    parser.add_argument("--healthz-limit", type=float, default=0.1)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON")
    args = parser.parse_args(argv)
    figures = run_soak(args.clients, args.seconds, args.wait, args.healthz_limit)
    if args.json:
        print(json.dumps(figures, indent=2))
    else:
        for name, value in figures.items():
            print(f"{name}: {value}")
    slow = figures["healthz_max_ms"] > args.healthz_limit * 1000
    return 1 if figures["failure_count"] or slow else 0


if __name__ == "__main__":
    raise SystemExit(main())
