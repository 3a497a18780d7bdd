"""The files section's machinery on a tiny file: every table has its row, the CLI runs, and the
memory child reports. Never asserts speed: benchmarks/ reports timings."""

from pathlib import Path

import pytest

from benchmarks import datasets
from benchmarks.sections import files


@pytest.fixture(autouse=True)
def private_cache(tmp_path, monkeypatch):
    monkeypatch.setattr(datasets, "CACHE", tmp_path / "cache")


@pytest.mark.slow
def test_the_files_section_reads_writes_and_runs_the_cli_beside_its_references(monkeypatch):
    monkeypatch.setattr(files, "QUICK", files.FilesPlan(detections=1_000, repeats=2))
    section = files.run(quick=True).to_dict()
    read, write, cli, phases = section["tables"]
    assert len(read["rows"]) == 1 and len(cli["rows"]) == 1
    assert len(write["rows"]) == 4  # CLI JSON, stored JSON, its former writer, matrix
    assert [row["phase"] for row in phases["rows"]] == [
        *files.CLI_PHASES,
        "all but the association",
    ]
    # Every phase was timed inside the CLI's process, and they add up to less than its run.
    medians = {row["phase"]: row["seconds"]["median"] for row in phases["rows"]}
    assert all(medians[phase] > 0 for phase in files.CLI_PHASES)
    assert medians["all but the association"] < cli["rows"][0]["CLI end to end"]["median"]
    assert section["settings"] == {"detections": 1_000, "repeats": 2}


def test_the_cli_is_timed_on_roadlinks_compiled_bytecode():
    """As installed (pip compiles a wheel's modules), whatever PYTHONDONTWRITEBYTECODE says."""
    import importlib.util

    package = files.compiled_roadlink()
    source = package / "cli" / "analysis.py"
    cached = Path(importlib.util.cache_from_source(str(source)))
    assert cached.is_file() and cached.stat().st_mtime >= source.stat().st_mtime
