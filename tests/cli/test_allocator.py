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


def test_associating_a_file_sets_the_allocator_first(monkeypatch, tmp_path):
    calls = []
    monkeypatch.setattr(analysis, "keep_freed_memory", lambda: calls.append(True) or True)
    path = tmp_path / "d.csv"
    path.write_text("position,velocity,timestamp\n0,20,1\n100,20,6\n")
    analysis.associate_file(path, "assignment", [])
    assert calls == [True]


def test_not_glibc_is_no_error(monkeypatch):
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    assert allocator.keep_freed_memory() is False
