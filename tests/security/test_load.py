"""A bounded load on loopback: 32 gateways post batches for a few seconds (benchmarks/load.py
runs the full 30 s); not one request fails. The figures are printed, not asserted: speed goals
live in benchmarks/."""

from __future__ import annotations

import json
import math
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SCRIPT = Path(__file__).resolve().parents[2] / "benchmarks" / "load.py"


def test_32_gateways_for_a_few_seconds_without_an_error() -> None:
    run = subprocess.run(
        [sys.executable, str(SCRIPT), "--gateways", "32", "--seconds", "5", "--json"],
        capture_output=True,
        text=True,
        timeout=180,
    )
    assert run.returncode == 0, run.stderr[-3000:]
    figures = json.loads(run.stdout)
    print(figures)
    assert figures["errors"] == 0, figures["first_error"]
    assert figures["requests"] >= figures["gateways"], "every gateway got answers"
    assert math.isfinite(figures["p99_ms"]) and figures["server_peak_rss_mib"] > 0
