"""Load on loopback: N gateways post detection batches to one `roadlink serve`, as fast as they get
answers, for S seconds.

    .venv/bin/python benchmarks/load.py                      # 32 gateways for 30 s
    .venv/bin/python benchmarks/load.py --gateways 8 --seconds 5 --json

The server is started here on a fresh SQLite file, with authentication on (each gateway has its
own ingest key, so each has its own rate-limit bucket at the default settings) and no queue
workers (this measures the API's ingest path). Each batch is one sensor's detections of the
paper's large scenario (10 detections), the way a gateway per sensor posts. Reports requests,
errors (any non-2xx, 429 included), latency percentiles, and the server's peak resident memory
(VmHWM of the `roadlink serve` process).
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from pathlib import Path

import httpx
import numpy as np

from roadlink.association.csvio import write_detections_csv
from roadlink.db.apikeys import create_api_key
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.models import ApiKeyScope
from roadlink.simulation import preset, simulate


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _roadlink(*argv: str, env: dict[str, str], cwd: Path) -> str:
    done = subprocess.run(
        [sys.executable, "-m", "roadlink.cli", *argv],
        cwd=cwd,
        env=env,
        capture_output=True,
        text=True,
        timeout=120,
        check=True,
    )
    return done.stdout.strip()


def _ingest_keys(database_url: str, deployment: str, n: int) -> list[str]:
    """`n` ingest keys of the deployment (as `roadlink keys create` makes them, in one go)."""
    engine = make_engine(database_url)
    try:
        with transaction(make_session_factory(engine)) as session:
            return [
                create_api_key(
                    session, scope=ApiKeyScope.INGEST, deployment_ids=[uuid.UUID(deployment)]
                ).key
                for _ in range(n)
            ]
    finally:
        engine.dispose()


def _peak_rss_mib(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def run_load(gateways: int, seconds: float) -> dict[str, float | int | str]:
    """Start a server, drive it with `gateways` concurrent clients for `seconds`; the figures."""
    directory = Path(tempfile.mkdtemp(prefix="roadlink-load-"))
    env = {
        **os.environ,
        "ROADLINK_DATABASE_URL": f"sqlite:///{directory / 'roadlink.db'}",
        "ROADLINK_LOG_LEVEL": "warning",
    }
    admin = _roadlink("keys", "create", "--scope", "admin", env=env, cwd=directory)
    port = _free_port()
    url = f"http://127.0.0.1:{port}"
    log = (directory / "serve.log").open("wb")
    server = subprocess.Popen(
        [sys.executable, "-m", "roadlink.cli", "serve", "--port", str(port), "--workers", "0"],
        cwd=directory,
        env=env,
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    try:
        deadline = time.monotonic() + 60
        while True:
            if server.poll() is not None:
                raise RuntimeError((directory / "serve.log").read_text())
            try:
                if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the server did not become ready")
            time.sleep(0.1)
        deployment = httpx.post(
            f"{url}/v1/deployments",
            json={"name": "load"},
            headers={"Authorization": f"Bearer {admin}"},
        ).json()["id"]
        keys = _ingest_keys(env["ROADLINK_DATABASE_URL"], deployment, gateways)
        detections = simulate(preset("large"), seed=1).detections
        sensors = sorted(set(detections.sensor_id.tolist()))
        bodies = [
            write_detections_csv(detections.take(np.flatnonzero(detections.sensor_id == s)))
            for s in sensors
        ]
        latencies: list[list[float]] = [[] for _ in range(gateways)]
        errors: list[str] = []
        start = threading.Barrier(gateways + 1)
        stop_at = [0.0]

        def gateway(k: int) -> None:
            headers = {"Authorization": f"Bearer {keys[k]}", "content-type": "text/csv"}
            with httpx.Client(base_url=url, headers=headers, timeout=30) as http:
                start.wait()
                n = 0
                while time.monotonic() < stop_at[0]:
                    body = bodies[(k + n) % len(bodies)]
                    began = time.perf_counter()
                    try:
                        answer = http.post(f"/v1/deployments/{deployment}/batches", content=body)
                        ok = answer.status_code == 201
                        what = f"{answer.status_code} {answer.text[:200]}"
                    except httpx.HTTPError as exc:
                        ok, what = False, repr(exc)
                    latencies[k].append(time.perf_counter() - began)
                    if not ok:
                        errors.append(what)
                    n += 1

        threads = [threading.Thread(target=gateway, args=(k,)) for k in range(gateways)]
        for thread in threads:
            thread.start()
        began = time.monotonic()
        stop_at[0] = began + seconds
        start.wait()
        for thread in threads:
            thread.join()
        elapsed = time.monotonic() - began
        peak = _peak_rss_mib(server.pid)
        every = np.array([x for per in latencies for x in per])
        return {
            "gateways": gateways,
            "seconds": round(elapsed, 2),
            "requests": int(every.size),
            "errors": len(errors),
            "requests_per_second": round(every.size / elapsed, 1),
            "p50_ms": round(float(np.percentile(every, 50)) * 1000, 1),
            "p99_ms": round(float(np.percentile(every, 99)) * 1000, 1),
            "max_ms": round(float(every.max()) * 1000, 1),
            "server_peak_rss_mib": round(peak, 1),
            "first_error": errors[0] if errors else "",
        }
    finally:
        server.terminate()
        try:
            server.wait(20)
        except subprocess.TimeoutExpired:
            server.kill()
            server.wait()
        log.close()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--gateways", type=int, default=32)
    parser.add_argument("--seconds", type=float, default=30.0)
    parser.add_argument("--json", action="store_true", help="Print the figures as JSON.")
    args = parser.parse_args()
    figures = run_load(args.gateways, args.seconds)
    if args.json:
        print(json.dumps(figures))
        return
    for name, value in figures.items():
        print(f"{name:>22}: {value}")


if __name__ == "__main__":
    main()
