"""The one-shot commands set glibc's allocator to keep freed memory for their next arrays."""

import platform
import subprocess
import sys
import threading

from roadlink.association.associators import ASSOCIATORS
from roadlink.association.csvio import READER_IMPORTS, SMALL_BYTES
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


def test_the_heap_is_faulted_in_for_a_large_file_only(monkeypatch, tmp_path):
    """A file's rows are estimated from its size and first lines; a file whose association
    needs less heap than the minimum, stdin and a missing file get no thread."""
    path = tmp_path / "d.csv"
    path.write_text("position,velocity,timestamp\n" + "0,20,1\n" * 10_000)
    assert 9_000 < allocator._estimated_rows(path) < 11_000
    assert allocator.fault_in_heap_for(path, 200) is None  # 2 MB of heap: not worth a thread
    assert allocator.fault_in_heap_for(tmp_path / "missing.csv", 200) is None
    assert allocator.fault_in_heap_for(tmp_path, 200) is None  # not a regular file
    monkeypatch.setattr(allocator, "MIN_HEAP_TO_FAULT_IN", 1 << 20)
    assert allocator.fault_in_heap_for(path, 0) is None  # an associator that did not say
    thread = allocator.fault_in_heap_for(path, 200)
    if platform.libc_ver()[0] != "glibc":
        assert thread is None
        return
    assert thread is not None
    thread.join()
    monkeypatch.setattr(allocator.sys, "platform", "darwin")
    assert allocator.fault_in_heap_for(path, 200) is None


def test_associating_a_file_faults_in_its_heap_and_imports_beside_the_read(monkeypatch, tmp_path):
    started, imported = [], []
    real = allocator.fault_in_heap_for
    monkeypatch.setattr(
        analysis, "fault_in_heap_for", lambda p, b: started.append((p, b)) or real(p, b)
    )
    monkeypatch.setattr(analysis.importlib, "import_module", imported.append)
    path = tmp_path / "d.csv"
    rows = "".join(f"{k % 7 * 100},20,{k % 7 * 5 + k}\n" for k in range(SMALL_BYTES // 10))
    path.write_text("position,velocity,timestamp\n" + rows)
    analysis.associate_file(path, "assignment", [])
    assignment = ASSOCIATORS["assignment"]
    assert started == [(path, assignment.heap_per_detection)]
    assert imported == [*READER_IMPORTS, *assignment.imports_on_first_use]
    assert analysis._importing(()) is None


def test_a_small_file_is_read_without_importing_the_fast_parser_beside_it(monkeypatch, tmp_path):
    """The exact reader takes a small file (`csvio.SMALL_BYTES`): polars is not imported."""
    imported = []
    monkeypatch.setattr(analysis.importlib, "import_module", imported.append)
    path = tmp_path / "d.csv"
    path.write_text("position,velocity,timestamp\n0,20,1\n100,20,6\n")
    analysis.associate_file(path, "assignment", [])
    assert imported == list(ASSOCIATORS["assignment"].imports_on_first_use)


def test_a_module_that_fails_to_import_beside_the_read_is_left_to_its_user(monkeypatch):
    """The import thread stops quietly: the code that needs the module imports it itself, and
    its error then names what is missing where it matters."""
    tried = []

    def missing(name):
        tried.append(name)
        raise ImportError(f"No module named {name!r}")

    monkeypatch.setattr(analysis.importlib, "import_module", missing)
    failures = []
    monkeypatch.setattr(threading, "excepthook", failures.append)
    thread = analysis._importing(("nothing_here", "nor_here"))
    assert thread is not None
    thread.join()
    assert tried == ["nothing_here"] and failures == []
