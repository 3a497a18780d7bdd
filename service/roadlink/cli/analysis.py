"""Commands that run the core without a server: simulate, associate, reproduce."""

from __future__ import annotations

import importlib
import sys
import threading
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Annotated

import typer
from pydantic import ValidationError

from roadlink.association import (
    AssociationResult,
    DetectionError,
    Detections,
    associate,
    key_values,
)
from roadlink.association.associators import ASSOCIATORS, DEFAULT_ASSOCIATOR, AssociationError
from roadlink.association.csvio import (
    read_detections_csv,
    reader_imports,
    write_detections_csv,
)
from roadlink.association.result import truth_of_detections
from roadlink.association.result_text import (
    DetectionTexts,
    json_detection_texts,
    write_result_json,
)
from roadlink.association.scores import Truth
from roadlink.cli.allocator import (
    fault_in_heap_for,
    keep_freed_memory,
    release_freed_memory,
)
from roadlink.cli.root import app
from roadlink.plots import PLOT_FORMATS, PLOT_KINDS, render_plot
from roadlink.simulation import PRESETS, preset, simulate
from roadlink.simulation.config import DEFAULT_LANE_CHANGE_PROBABILITY

# The options every command that associates takes.
AssociatorOption = Annotated[str, typer.Option(help=f"One of: {', '.join(ASSOCIATORS)}.")]
ParamOption = Annotated[
    list[str] | None, typer.Option("--param", help="Associator parameter key=value (repeat).")
]


def fail(message: str) -> typer.Exit:
    """Print an error a person can act on, and exit with status 2 (bad input)."""
    typer.echo(f"error: {message}", err=True)
    return typer.Exit(code=2)


def settings_problem(exc: ValueError) -> str:
    """A settings error as a line a person reads: each field and what is wrong with it (not
    pydantic's report, which repeats every input value)."""
    if not isinstance(exc, ValidationError):
        return str(exc)
    return "; ".join(
        (f"{'.'.join(map(str, e['loc']))}: " if e["loc"] else "")
        + str(e["msg"]).removeprefix("Value error, ")
        for e in exc.errors()
    )


def plot_format_of(path: Path) -> str:
    """The plot format named by a file's suffix (.png or .svg); exit 2 otherwise."""
    fmt = path.suffix.lower().lstrip(".")
    if fmt not in PLOT_FORMATS:
        raise fail(f"--plot file must end in .png or .svg, got '{path.name}'")
    return fmt


def parse_param_options(values: list[str]) -> dict[str, str]:
    """`key=value` options into a dict; the associator's schema converts the values."""
    try:
        return key_values(values)
    except ValueError as exc:
        raise fail(f"--param: {exc}") from None


def associate_file(
    file: Path,
    associator: str,
    param: list[str],
    meanwhile: Callable[[Detections], object] | None = None,
    *,
    scored: bool = True,
) -> AssociationResult:
    """Read a detection CSV ('-' = stdin) and associate it; exit 2 with the reason on bad input.
    `meanwhile(detections)` runs on a thread while they are associated: what the command does
    next that does not need the grouping, on the core the association leaves idle. Unless
    `scored`, the result's metrics are left to `AssociationResult.scored`."""
    keep_freed_memory()  # the command associates once and ends (see `allocator`)
    preparing = _prepare_beside_the_read(file, associator)
    detections = _read(file)
    for thread in preparing:
        thread.join()
    try:
        with ThreadPoolExecutor(max_workers=1, thread_name_prefix="roadlink-meanwhile") as pool:
            beside = None if meanwhile is None else pool.submit(meanwhile, detections)
            params = parse_param_options(param)
            result = associate(detections, associator, params, scored=scored)
            if beside is not None:
                beside.result()
            return result
    except (DetectionError, AssociationError) as exc:
        raise fail(f"{file}: {exc}") from None
    finally:
        release_freed_memory()


def _read(file: Path) -> Detections:
    try:
        # Bytes from stdin: the fast path (polars) reads them as they are, without a decoded
        # copy; a file is mapped, and polars reads it itself.
        return read_detections_csv(sys.stdin.buffer.read() if str(file) == "-" else file)
    except OSError as exc:
        raise fail(f"cannot read {file}: {exc.strerror}") from None
    except UnicodeDecodeError as exc:
        raise fail(f"{file}: not UTF-8 text: byte {exc.start + 1} ({exc.reason})") from None
    except DetectionError as exc:
        raise fail(f"{file}: {exc}") from None


def _prepare_beside_the_read(file: Path, associator: str) -> list[threading.Thread]:
    """Start what the association will need and the read does not wait for, on threads: the
    heap it will take (`allocator.fault_in_heap_for`) and its imports. The reader's imports
    (none for a small file, which the exact reader takes: `csvio.reader_imports`) come first,
    so the read waits for them alone, then parses (without the GIL) while the
    associator's are imported (read and imports 0.55-0.89 -> 0.48-0.61 s at 10^6; importing
    both at once kept polars' import waiting on the GIL)."""
    cls = ASSOCIATORS.get(associator)  # an unknown one: `associate` names the known ones
    heap = 0 if cls is None else cls.heap_per_detection
    reader = reader_imports(None if str(file) == "-" else _size(file))
    imports = (*reader, *(() if cls is None else cls.imports_on_first_use))
    threads = [
        None if str(file) == "-" else fault_in_heap_for(file, heap),
        _importing(imports),
    ]
    return [thread for thread in threads if thread is not None]


def _size(file: Path) -> int | None:
    """The file's size in bytes (None where it cannot be read: the read says why)."""
    try:
        return file.stat().st_size
    except OSError:
        return None


def _importing(modules: tuple[str, ...]) -> threading.Thread | None:
    """Start importing `modules` in order on a thread (a module the read needs that the thread
    is importing, the read waits for); None for none. A module that fails to import is left
    to the code that needs it, whose own import then says why."""

    def import_all() -> None:
        try:
            for name in modules:
                importlib.import_module(name)
        except ImportError:
            return

    if not modules:
        return None
    thread = threading.Thread(target=import_all, name="roadlink-imports")
    thread.start()
    return thread


@app.command("simulate")
def simulate_command(
    output: Annotated[
        Path, typer.Option("-o", "--output", help="CSV file to write ('-' = stdout).")
    ],
    preset_name: Annotated[
        str, typer.Option("--preset", help=f"One of: {', '.join(PRESETS)}.")
    ] = "large",
    seed: Annotated[int, typer.Option(help="Random seed (same seed, same data).")] = 0,
    targets: Annotated[int | None, typer.Option(help="Number of targets.")] = None,
    sensors: Annotated[
        int | None, typer.Option(help="Number of sensors, evenly spaced 100 m apart from 0.")
    ] = None,
    velocity_fluctuation: Annotated[
        float | None, typer.Option(help="OU velocity std as a share of v0 (0 = constant).")
    ] = None,
    miss: Annotated[float, typer.Option(help="Probability of a missed detection.")] = 0.0,
    false_alarms: Annotated[float, typer.Option(help="False alarms per true detection.")] = 0.0,
    duplicates: Annotated[float, typer.Option(help="Probability of a duplicated detection.")] = 0.0,
    unlabelled: Annotated[bool, typer.Option(help="Leave the target column empty.")] = False,
    lanes: Annotated[
        int | None,
        typer.Option(help="Report each detection's lane (0 = rightmost) on a road of N lanes."),
    ] = None,
    lane_change: Annotated[
        float | None,
        typer.Option(
            help="Chance that a vehicle changes to a neighbouring lane between two sensors "
            f"(with --lanes; default {DEFAULT_LANE_CHANGE_PROBABILITY})."
        ),
    ] = None,
    lengths: Annotated[
        bool,
        typer.Option(
            help="Report each vehicle's length (cars 80 %, vans 10 %, trucks 8 %, buses 2 %)."
        ),
    ] = False,
    length_noise: Annotated[
        float,
        typer.Option(help="Length measurement error, std as a share of length (with --lengths)."),
    ] = 0.0,
    classes: Annotated[
        bool, typer.Option(help="Report each vehicle's class (car, van, truck or bus).")
    ] = False,
) -> None:
    """Generate labelled detections with the paper's Algorithm 1 and write them as CSV.
    Lanes, lengths and classes are off by default (the paper's detector reports none)."""
    overrides: dict[str, object] = {
        "miss_probability": miss,
        "false_alarm_rate": false_alarms,
        "duplicate_probability": duplicates,
        "lanes": lanes,
        "vehicle_lengths": lengths,
        "length_noise": length_noise,
        "vehicle_classes": classes,
    }
    optional = {
        "n_targets": targets,
        "sensor_positions": None if sensors is None else [100.0 * i for i in range(sensors)],
        "velocity_fluctuation": velocity_fluctuation,
        "lane_change_probability": lane_change,
    }
    overrides.update({name: value for name, value in optional.items() if value is not None})
    try:
        config = preset(preset_name, **overrides)
    except ValueError as exc:
        raise fail(settings_problem(exc)) from None
    write_simulated(simulate(config, seed=seed).detections, output, unlabelled=unlabelled)


def write_simulated(detections: Detections, output: Path, *, unlabelled: bool) -> None:
    """Write simulated detections as CSV to a file or, for '-', to stdout."""
    if unlabelled:
        detections = detections.without_labels()
    text = write_detections_csv(detections)
    if str(output) == "-":
        sys.stdout.write(text)
    else:
        output.write_text(text)
        typer.echo(f"wrote {len(detections)} detections to {output}", err=True)


@app.command("associate")
def associate_command(
    file: Annotated[Path, typer.Argument(help="Detection CSV ('-' = stdin).")],
    associator: AssociatorOption = DEFAULT_ASSOCIATOR,
    param: ParamOption = None,
    as_json: Annotated[bool, typer.Option("--json", help="Print the result JSON.")] = False,
    as_csv: Annotated[
        bool, typer.Option("--csv", help="Print the target x sensor matrix (the paper's X'').")
    ] = False,
    plot: Annotated[
        Path | None,
        typer.Option("--plot", help="Also draw the result to this .png or .svg file."),
    ] = None,
    plot_kind: Annotated[
        str, typer.Option("--plot-kind", help=f"One of: {', '.join(PLOT_KINDS)}.")
    ] = "time-space",
) -> None:
    """Group the detections of a CSV file into targets, and score them when labelled."""
    if as_json and as_csv:
        raise fail("choose one of --json and --csv")
    plot_format = None if plot is None else plot_format_of(plot)
    if plot_kind not in PLOT_KINDS:
        raise fail(f"unknown --plot-kind '{plot_kind}'; known: {', '.join(PLOT_KINDS)}")
    beside: list[tuple[DetectionTexts, Truth]] = []
    made_beside = (lambda d: beside.append(_json_beside(d))) if as_json else None
    # The JSON's metrics come last: it is scored while its rows are written (`write_json`).
    scored_now = not as_json or plot is not None
    result = associate_file(file, associator, param or [], made_beside, scored=scored_now)
    if plot is not None and plot_format is not None:
        try:
            plot.write_bytes(render_plot(result, plot_kind, plot_format))
        except OSError as exc:
            raise fail(f"cannot write {plot}: {exc.strerror}") from None
        typer.echo(f"wrote {plot_kind} plot to {plot}", err=True)
    if as_json:
        texts, truth = beside[0] if beside else (None, None)
        write_json(result, texts, truth, scored=scored_now)
    elif as_csv:
        sys.stdout.write(result.to_matrix_csv())
    else:
        print_summary(summary_of(result))


def _json_beside(detections: Detections) -> tuple[DetectionTexts, Truth]:
    """What `write_json` takes of the detections alone, made while they are associated: the
    rows' text and the true labels as the scoring reads them."""
    return json_detection_texts(detections), truth_of_detections(detections)


def write_json(
    result: AssociationResult,
    texts: DetectionTexts | None,
    truth: Truth | None,
    *,
    scored: bool,
) -> None:
    """The result JSON to stdout, as bytes straight to the stream (the text of 10^6 detections
    is hundreds of MiB); an unscored result is scored on a thread while its rows are written
    (10^6 detections, the labels read beforehand: 0.04 s of scoring beside 0.4-0.5 s of
    writing). `texts` and `truth`, when given, were made from the detections beforehand
    (`_json_beside`)."""
    sys.stdout.flush()
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="roadlink-scoring") as pool:
        scoring = None if scored else pool.submit(result.scored, truth)
        metrics = None if scoring is None else (lambda: scoring.result().metrics)
        write_result_json(result, sys.stdout.buffer, texts, metrics=metrics)
    sys.stdout.buffer.flush()


def summary_of(result: AssociationResult) -> dict[str, object]:
    """What `print_summary` reads of the result document, without building the document."""
    return {
        "associator": result.associator,
        "n_detections": len(result.detections),
        "n_targets": result.n_targets,
        "unassigned": range(int((result.groups < 0).sum())),
        "metrics": None if result.metrics is None else result.metrics.to_dict(),
    }


def print_summary(result: dict[str, object]) -> None:
    typer.echo(
        f"{result['associator']}: {result['n_detections']} detections -> "
        f"{result['n_targets']} targets, {len(result['unassigned'])} unassigned"  # type: ignore[arg-type]
    )
    metrics = result["metrics"]
    if isinstance(metrics, dict):
        typer.echo("  " + "  ".join(f"{k}={v:.4f}" for k, v in metrics.items()))
