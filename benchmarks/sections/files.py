"""Files: reading a detection CSV, writing a result, and `roadlink associate` end to end, each
as a ratio against a reference measured in the same run (issue 19).

- CSV in: `read_detections_csv` (parse and validate, the CLI's and `text/csv` ingest's reader)
  beside polars' `read_csv` of the same file, interleaved; goal: at least half its speed. Peak
  memory of the read, in a process of its own, above that process's baseline (after its
  imports and a first read of a two-line file, which starts polars' thread pool and allocator
  once per process: reported beside), against the bytes of the arrays it produces (the columns
  and their strings); goal at most 3x. Both are timed reading the file by its path, as the CLI
  does (ours maps it into memory); the memory is the read's own, from the file's bytes loaded
  before the baseline.
- Out: the CLI's `--json` (`write_result_json` to /dev/null, as the CLI writes it to its
  stdout, bytes without a decoded copy), the service's stored JSON (`result_json_compact`;
  beside it what the service ran before, `orjson.dumps(result.to_dict())`, the same text) and
  the matrix (`to_matrix_csv`) of an `assignment` result, against that association's time;
  goal at most 10 % each.
- CLI: `roadlink associate FILE --json` in a subprocess, beside the in-process association of
  the same detections, interleaved; goal at most 1.15, and a peak of at most 1 GiB. The CLI
  runs on roadlink's compiled bytecode, as a user's does (`compiled_roadlink`). Beside the
  ratio of the medians: the median of each run's ratio to the association just before it, and
  where the CLI's time went (`CLI_PHASES`, timed inside its process). What the CLI adds to its
  own association is the figure that the machine's drift over a run disturbs least.

The `csv-read` section (`python -m benchmarks --only csv-read`) runs the CSV-in table alone, on
the same file with more repeats: a minute or so where `files` takes several (its 10^6-detection
association), for iterating on the reader.
"""

from __future__ import annotations

import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import orjson
import polars as pl

from benchmarks.datasets import cached_dataset, load_detections, scaled_config, targets_for
from benchmarks.report import Column, Sample, Section, Table
from roadlink.association import AssociationResult, associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.result_text import result_json_compact, write_result_json

NAME = "files"
GOAL_READ_SPEED = 0.5
GOAL_READ_MEMORY = 3.0
GOAL_WRITE_SHARE = 0.10
GOAL_CLI_RATIO = 1.15
GOAL_CLI_PEAK_MIB = 1024


@dataclass(frozen=True)
class FilesPlan:
    """Detections in the file and repeats of each measurement."""

    detections: int
    repeats: int


FULL = FilesPlan(detections=1_000_000, repeats=5)
QUICK = FilesPlan(detections=100_000, repeats=3)

READ_NAME = "csv-read"
READ_FULL = FilesPlan(detections=1_000_000, repeats=7)
READ_QUICK = FilesPlan(detections=100_000, repeats=7)


def timed(action: Callable[[], object]) -> float:
    """Seconds `action` took. Its result is freed after the clock stops: freeing a million
    `str` ids is the caller's cost when it is done with them, not the read's."""
    start = time.perf_counter()
    result = action()
    elapsed = time.perf_counter() - start
    del result
    return elapsed


def read_memory(path: Path) -> dict[str, float]:
    """Peak memory of reading `path`, in a child process: MiB above its baseline (after its
    imports and a first read of a two-line file), the MiB of the arrays the
    read produced, and what that first read cost (polars' one-time start)."""
    script = (
        "import json, sys; from pathlib import Path;"
        "from benchmarks.sections.files import measure_read_memory;"
        "print(json.dumps(measure_read_memory(Path(sys.argv[1]))))"
    )
    out = subprocess.run(
        [sys.executable, "-c", script, str(path)],
        check=True,
        capture_output=True,
        text=True,
        cwd=Path(__file__).resolve().parents[2],
    )
    return dict(json.loads(out.stdout))


def measure_read_memory(path: Path) -> dict[str, float]:
    """Run in the child of `read_memory`."""
    from benchmarks.isolated import peak_rss_kib

    # The file's bytes before the baseline: the read's own memory is measured, not the
    # input's (mapped by the CLI's read, its pages are the page cache's).
    data = path.read_bytes()
    before_start = _current_rss_kib()
    read_detections_csv(_TWO_LINES)  # polars' thread pool and allocator, once per process
    baseline = _current_rss_kib()
    detections = read_detections_csv(data)
    peak = peak_rss_kib() or 0
    produced = 0
    for name in ("position", "velocity", "timestamp", "lane", "length"):
        produced += getattr(detections, name).nbytes
    texts = ["sensor_id", "vehicle_class"]
    for name in ("detection_id", "target"):
        parsed = detections.parsed_texts(name)
        if parsed is None:
            texts.append(name)
        else:  # held as polars' column (`ParsedTexts`): counted so, not as the strs it makes
            produced += int(parsed.estimated_size())
    for name in texts:
        column = getattr(detections, name)
        produced += column.nbytes
        produced += sum(sys.getsizeof(v) for v in {id(v): v for v in column.tolist()}.values())
    return {
        "above_baseline_mib": (peak - baseline) / 1024,
        "arrays_mib": produced / 2**20,
        "start_mib": (baseline - before_start) / 1024,
    }


_TWO_LINES = b"position,velocity,timestamp,sensor_id,detection_id,target\n0,20,1,S1,d1,A\n"


def _current_rss_kib() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return 0


def json_to_devnull(result: AssociationResult) -> None:
    """What `roadlink associate --json` does with its result: its bytes to a stream."""
    with open(os.devnull, "wb") as sink:
        write_result_json(result, sink)


def compiled_roadlink() -> Path:
    """Write roadlink's bytecode (its package directory, returned), as a user's install has it:
    pip compiles a wheel's modules as it installs them, and an editable install's first run
    writes them. Where the environment sets PYTHONDONTWRITEBYTECODE (this project's
    development machines do), an editable install never does, and every CLI run would compile
    roadlink's sources anew: 0.08 s of its start (AMD EPYC), which no user pays."""
    import compileall

    import roadlink

    package = Path(roadlink.__file__).parent
    compileall.compile_dir(package, quiet=1)
    return package


@dataclass(frozen=True)
class CliRun:
    """One `roadlink associate FILE --json`: its wall time, its peak MiB, and where the time
    went (`CLI_PHASES`), each in seconds."""

    seconds: float
    peak_mib: float
    phases: dict[str, float]


# Where a CLI run's time goes: Python's start and the imports up to the read (with what
# `_prepare_beside_the_read` starts), the read, the association, the JSON's writing (scored
# beside it), and what is left: the steps between them and the interpreter's end.
CLI_PHASES = ("start and imports", "read", "association", "writing", "rest and exit")


def cli_run(path: Path) -> CliRun:
    """Time and peak of `roadlink associate FILE --json`, its output discarded.

    The peak is the CLI process's own high-water mark (VmHWM), which it reports on exit
    (`_REPORTING_CLI`): the `ru_maxrss` that wait4 gives counts the parent's resident set too,
    as the child was forked from it before it started the CLI. The phases are read off the
    monotonic clock, which parent and child share: the child times the CLI's own read,
    association and writing (`_REPORTING_CLI` wraps them), and the parent reads them from the
    moment it started the child."""
    start = time.perf_counter()
    command = [sys.executable, "-c", _REPORTING_CLI, "associate", str(path), "--json"]
    with open(os.devnull, "wb") as sink:
        done = subprocess.run(command, stdout=sink, stderr=subprocess.PIPE, text=True)
    elapsed = time.perf_counter() - start
    if done.returncode != 0:
        raise RuntimeError(f"{command} exited with {done.returncode}: {done.stderr}")
    report = json.loads(done.stderr.strip().splitlines()[-1])
    marks = report["marks"]
    phases = {
        "start and imports": marks["_read"][0] - start,
        "read": marks["_read"][1] - marks["_read"][0],
        "association": marks["associate"][1] - marks["associate"][0],
        "writing": marks["write_json"][1] - marks["write_json"][0],
    }
    phases["rest and exit"] = elapsed - sum(phases.values())
    return CliRun(elapsed, report["vmhwm_kib"] / 1024, phases)


# `python -m roadlink.cli ARGS`, each of its read, association and writing timed, then a JSON
# line on stderr: those times (on the monotonic clock) and the peak resident set.
_REPORTING_CLI = """
import json, runpy, sys, time
from pathlib import Path
import roadlink.cli.analysis as command
marks = {}
def timing(name):
    run = getattr(command, name)
    def timed(*args, **kwargs):
        begun = time.perf_counter()
        try:
            return run(*args, **kwargs)
        finally:
            marks[name] = (begun, time.perf_counter())
    setattr(command, name, timed)
for name in ("_read", "associate", "write_json"):
    timing(name)
sys.argv = ["roadlink", *sys.argv[1:]]
try:
    runpy.run_module("roadlink.cli", run_name="__main__", alter_sys=True)
finally:
    peak = 0
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            peak = int(line.split()[1])
    print(json.dumps({"vmhwm_kib": peak, "marks": marks}), file=sys.stderr)
"""


@contextmanager
def detection_file(plan: FilesPlan) -> Iterator[Path]:
    """The plan's detection CSV (the scaling data of `associators`), in a temporary directory."""
    detections = load_detections(cached_dataset(scaled_config(targets_for(plan.detections))))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "detections.csv"
        path.write_text(write_detections_csv(detections))
        yield path


def run(quick: bool) -> Section:
    """The files section (see the module docstring)."""
    plan = QUICK if quick else FULL
    with detection_file(plan) as path:
        read = _read_table(path, plan)
        write, cli, phases = _write_and_cli_tables(path, plan)
    return Section(
        NAME,
        f"A {plan.detections:,}-detection CSV (the scaling data of `associators`): reading "
        "it, writing its result, and the CLI end to end, each beside its reference in the same "
        f"run. Median [min, max] of {plan.repeats} interleaved repeats.",
        tables=[read, write, cli, phases],
        settings={"detections": plan.detections, "repeats": plan.repeats},
    )


def run_read(quick: bool) -> Section:
    """The CSV-in table of `files` alone (see the module docstring)."""
    plan = READ_QUICK if quick else READ_FULL
    with detection_file(plan) as path:
        read = _read_table(path, plan)
    return Section(
        READ_NAME,
        f"A {plan.detections:,}-detection CSV (the file of `files`): reading it beside polars. "
        f"Median [min, max] of {plan.repeats} interleaved repeats.",
        tables=[read],
        settings={"detections": plan.detections, "repeats": plan.repeats},
    )


def _read_table(path: Path, plan: FilesPlan) -> Table:
    ours: list[float] = []
    theirs: list[float] = []
    with_strs: list[float] = []
    for _ in range(plan.repeats + 1):
        theirs.append(timed(lambda: pl.read_csv(path)))
        ours.append(timed(lambda: read_detections_csv(path)))
        with_strs.append(timed(lambda: read_detections_csv(path).detection_id))
    ours, theirs, with_strs = ours[1:], theirs[1:], with_strs[1:]  # the first: a warm-up
    speed = Sample.of(theirs).median / Sample.of(ours).median
    memory = read_memory(path)
    memory_ratio = memory["above_baseline_mib"] / memory["arrays_mib"]
    table = Table(
        "CSV in: read_detections_csv beside polars.read_csv",
        [
            Column("detections", "count"),
            Column("polars.read_csv", "seconds"),
            Column("read_detections_csv", "seconds"),
            Column("speed / polars"),
            Column("goal >= 0.5"),
            Column("and the ids as str", "seconds"),
            Column("its speed / polars"),
            Column("peak above baseline", "mib"),
            Column("arrays produced", "mib"),
            Column("peak / arrays"),
            Column("goal <= 3"),
            Column("polars' start (once)", "mib"),
        ],
    )
    table.add(
        plan.detections,
        Sample.of(theirs),
        Sample.of(ours),
        f"{speed:.2f}",
        _met(speed >= GOAL_READ_SPEED),
        Sample.of(with_strs),
        f"{Sample.of(theirs).median / Sample.of(with_strs).median:.2f}",
        memory["above_baseline_mib"],
        memory["arrays_mib"],
        f"{memory_ratio:.2f}",
        _met(memory_ratio <= GOAL_READ_MEMORY),
        memory["start_mib"],
    )
    table.notes.extend(
        [
            "- Both read the file by its path (ours maps it, as the CLI does); ours parses and "
            "validates into `Detections` (polars only parses, inferring types). Peak memory: the "
            "read of the file's bytes in a child process, VmHWM above its VmRSS once they are "
            "loaded and a two-line file read (polars' one-time start, shown beside); arrays: "
            "the columns and their strings (each distinct one once), the ids and labels as "
            "polars' columns, as the read holds them.",
            "- The detection ids and labels stay polars' columns until something reads them as "
            "Python strs (the CLI's and the service's JSON writers and the scoring never do): "
            "`and the ids as str` is the read followed by that first read of `detection_id`.",
        ]
    )
    return table


def _write_and_cli_tables(path: Path, plan: FilesPlan) -> tuple[Table, Table, Table]:
    detections = read_detections_csv(path)
    association: list[float] = []
    cli: list[CliRun] = []
    writers: dict[str, Callable[[AssociationResult], object]] = {
        "CLI --json (write_result_json)": json_to_devnull,
        "service JSON (result_json_compact)": result_json_compact,
        "service JSON before (orjson of to_dict)": lambda r: orjson.dumps(r.to_dict()),
        "matrix CSV (to_matrix_csv)": lambda r: r.to_matrix_csv(),
    }
    writes: dict[str, list[float]] = {name: [] for name in writers}
    compiled_roadlink()
    for _ in range(plan.repeats):
        start = time.perf_counter()
        result = associate(detections, DEFAULT_ASSOCIATOR, {})
        association.append(time.perf_counter() - start)
        for name, write in writers.items():
            start = time.perf_counter()
            write(result)
            writes[name].append(time.perf_counter() - start)
        cli.append(cli_run(path))
    reference = Sample.of(association)
    write_table = Table(
        f"Out: writing a {plan.detections:,}-detection result / its association",
        [
            Column("writer"),
            Column("seconds", "seconds"),
            Column(f"{DEFAULT_ASSOCIATOR} association", "seconds"),
            Column("share"),
            Column("goal <= 10 %"),
        ],
    )
    for name, runs in writes.items():
        share = Sample.of(runs).median / reference.median
        write_table.add(
            name, Sample.of(runs), reference, f"{share:.1%}", _met(share <= GOAL_WRITE_SHARE)
        )
    end_to_end = Sample.of([run.seconds for run in cli])
    ratio = end_to_end.median / reference.median
    # Each run against the association just before it: the machine's speed drifts over a run
    # of `files` by as much as the goal's allowance (docs/benchmarks.md).
    paired = statistics.median(run.seconds / a for run, a in zip(cli, association, strict=True))
    peak = max(run.peak_mib for run in cli)
    cli_table = Table(
        "CLI: `roadlink associate FILE --json` / in-process association",
        [
            Column("detections", "count"),
            Column("CLI end to end", "seconds"),
            Column("in-process association", "seconds"),
            Column("ratio"),
            Column("goal <= 1.15"),
            Column("median of paired ratios"),
            Column("CLI peak", "mib"),
            Column("goal <= 1 GiB"),
        ],
    )
    cli_table.add(
        plan.detections,
        end_to_end,
        reference,
        f"{ratio:.2f}",
        _met(ratio <= GOAL_CLI_RATIO),
        f"{paired:.2f}",
        peak,
        _met(peak <= GOAL_CLI_PEAK_MIB),
    )
    cli_table.notes.append(
        "- The CLI in a subprocess (Python's start and imports included, on roadlink's "
        "compiled bytecode, as installed), its output to /dev/null; its peak is its own "
        "VmHWM, read as it exits (wait4's ru_maxrss would count this process's resident set, "
        "from which it was forked). Paired ratios: each CLI run over the in-process "
        "association run just before it."
    )
    return write_table, cli_table, _phase_table(cli, reference)


def _phase_table(cli: list[CliRun], reference: Sample) -> Table:
    """Where the CLI's time went (`CLI_PHASES`), each phase against the in-process
    association: what the command adds to it is everything but its own association."""
    table = Table(
        "CLI: where its time went / in-process association",
        [Column("phase"), Column("seconds", "seconds"), Column("share of the association")],
    )
    for phase in CLI_PHASES:
        runs = Sample.of([run.phases[phase] for run in cli])
        table.add(phase, runs, f"{runs.median / reference.median:.1%}")
    fixed = Sample.of([run.seconds - run.phases["association"] for run in cli])
    table.add("all but the association", fixed, f"{fixed.median / reference.median:.1%}")
    table.notes.append(
        "- Timed inside the CLI's process on the clock the parent started it by; `rest and "
        "exit` is the run's wall time less the phases before it. The goal's 15 % is the "
        "allowance for all but the association, if the CLI's association takes what the "
        "in-process one does."
    )
    return table


def _met(ok: bool) -> str:
    return "met" if ok else "missed"
