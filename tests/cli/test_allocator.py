"""The one-shot commands set glibc's allocator to keep freed memory for their next arrays."""

import platform
import subprocess
import sys

from roadlink.cli import allocator, analysis


def test_glibc_takes_the_settings_where_it_is_the_c_library():
    """On this Linux with glibc every setting is taken; elsewhere the call says it was not.
    Run in a process of its own: the settings outlive the call."""
    script = "from roadlink.cli.allocator import keep_freed_memory; print(keep_freed_memory())"
    done = subprocess.run(
        [sys.executable, "-c", script], capture_output=True, text=True, check=True
    )
    glibc = platform.libc_ver()[0] == "glibc"
    assert done.stdout.strip() == str(sys.platform.startswith("linux") and glibc)


def test_associating_a_file_keeps_freed_memory_then_gives_it_back(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr(analysis, "keep_freed_memory", lambda: calls.append("keep") or True)
    monkeypatch.setattr(analysis, "release_freed_memory", lambda: calls.append("release"))
    path = tmp_path / "d.csv"
    path.write_text("position,velocity,timestamp\n0,20,1\n100,20,6\n")
    analysis.associate_file(path, "assignment", [])
    assert calls == ["keep", "release"]


def test_giving_memory_back_runs_where_glibc_is_and_is_no_error_elsewhere(monkeypatch):
    allocator.release_freed_memory()
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    assert allocator.keep_freed_memory() is False
    allocator.release_freed_memory()
