"""`roadlink reproduce`: the paper's comparison table (and ours), with its bar chart."""

from __future__ import annotations

import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Annotated

import typer

from roadlink.cli.root import app

if TYPE_CHECKING:
    from roadlink.simulation.study import StudyRow

PAPER_PRESETS = ["large", "medium", "small"]


@app.command("reproduce")
def reproduce_command(
    seeds: Annotated[int, typer.Option(min=1, help="Simulated data sets per preset.")] = 100,
    preset: Annotated[
        list[str] | None, typer.Option(help="Preset to run (repeat); default: the paper's three.")
    ] = None,
    associator: Annotated[
        list[str] | None, typer.Option(help="Associator to run (repeat); default: all.")
    ] = None,
    plot: Annotated[Path, typer.Option(help="Where to write the accuracy bar chart (PNG).")] = Path(
        "reproduce.png"
    ),
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Also write the table as JSON here.")
    ] = None,
) -> None:
    """Every associator, with and without back-projection, over many seeds per preset."""
    presets = preset or PAPER_PRESETS
    from roadlink.simulation.study import run_study, study_variants

    variants = study_variants(associator)
    total = len(presets) * len(variants) * seeds
    with typer.progressbar(length=total, label="associating", file=sys.stderr) as bar:
        rows = run_study(presets, variants, seeds, on_step=lambda: bar.update(1))
    typer.echo(format_table(rows, presets, seeds))
    write_bar_chart(rows, presets, plot)
    typer.echo(f"bar chart written to {plot}", err=True)
    if json_out:
        json_out.write_text(json.dumps([_row_dict(r) for r in rows], indent=2) + "\n")


def format_table(rows: list[StudyRow], presets: list[str], seeds: int) -> str:
    """A Markdown table: one row per variant, one column per preset, mean +- std (min)."""
    labels = list(dict.fromkeys(r.variant.label for r in rows))
    cell = {(r.variant.label, r.preset): r for r in rows}
    lines = [
        f"Accuracy over {seeds} seeds per preset: mean ± std (worst)",
        "",
        "| associator | " + " | ".join(presets) + " |",
        "|---|" + "---|" * len(presets),
    ]
    for label in labels:
        cells = [
            f"{cell[label, p].mean:.1%} ± {cell[label, p].std:.1%} ({cell[label, p].minimum:.0%})"
            for p in presets
        ]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def write_bar_chart(rows: list[StudyRow], presets: list[str], path: Path) -> None:
    """Grouped bars like the paper's accuracy figure: one group per variant, a bar per preset."""
    labels = list(dict.fromkeys(r.variant.label for r in rows))
    cell = {(r.variant.label, r.preset): r for r in rows}
    from matplotlib.figure import Figure

    figure = Figure(figsize=(max(6.0, 0.9 * len(labels) + 2), 4.2), layout="constrained")
    axes = figure.add_subplot()
    width = 0.8 / len(presets)
    for k, name in enumerate(presets):
        xs = [i + (k - (len(presets) - 1) / 2) * width for i in range(len(labels))]
        axes.bar(
            xs,
            [100 * cell[label, name].mean for label in labels],
            width,
            yerr=[100 * cell[label, name].std for label in labels],
            capsize=2,
            label=name,
        )
    axes.set_xticks(range(len(labels)), labels, rotation=30, ha="right")
    axes.set_ylabel("accuracy (%)")
    axes.set_ylim(0, 105)
    figure.legend(title="preset", loc="outside upper center", ncols=len(presets))
    axes.grid(axis="y", alpha=0.3)
    figure.savefig(path, format="png", dpi=120)


def _row_dict(row: StudyRow) -> dict[str, object]:
    return {
        "preset": row.preset,
        "associator": row.variant.associator,
        "backproject": row.variant.backproject,
        "mean": row.mean,
        "std": row.std,
        "min": row.minimum,
        "accuracies": list(row.accuracies),
    }
