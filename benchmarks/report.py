"""What a section returns: tables whose cells may be repeated measurements (median and spread)."""

from __future__ import annotations

import statistics
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

Unit = Literal["text", "count", "seconds", "mib", "share"]


@dataclass(frozen=True)
class Sample:
    """Repeated measurements of one figure; reported as the median and the spread (min-max)."""

    runs: tuple[float, ...]

    def __post_init__(self) -> None:
        if not self.runs:
            raise ValueError("a sample needs at least one run")

    @classmethod
    def of(cls, runs: Sequence[float]) -> Sample:
        return cls(tuple(float(r) for r in runs))

    @property
    def median(self) -> float:
        return float(statistics.median(self.runs))

    @property
    def minimum(self) -> float:
        return min(self.runs)

    @property
    def maximum(self) -> float:
        return max(self.runs)

    @property
    def mean(self) -> float:
        return float(statistics.fmean(self.runs))

    def to_dict(self) -> dict[str, Any]:
        return {
            "median": self.median,
            "min": self.minimum,
            "max": self.maximum,
            "mean": self.mean,
            "n": len(self.runs),
            "runs": list(self.runs),
        }


Cell = Sample | float | int | str | None


@dataclass(frozen=True)
class Column:
    """A column's name, its unit, and which statistic of a sample it shows first.

    Timings show the median (robust to a noisy neighbour); accuracies over seeds show the mean,
    as the paper does. The JSON always holds both, and every run.
    """

    name: str
    unit: Unit = "text"
    statistic: Literal["median", "mean"] = "median"


@dataclass
class Table:
    """Rows of cells under named columns, with a title and notes printed below it."""

    title: str
    columns: list[Column]
    rows: list[list[Cell]] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)

    def add(self, *cells: Cell) -> None:
        if len(cells) != len(self.columns):
            raise ValueError(f"{len(cells)} cells for {len(self.columns)} columns in {self.title}")
        self.rows.append(list(cells))

    def to_markdown(self) -> str:
        head = "| " + " | ".join(c.name for c in self.columns) + " |"
        rule = "|" + "|".join("---" for _ in self.columns) + "|"
        body = [
            "| "
            + " | ".join(format_cell(c, col) for c, col in zip(row, self.columns, strict=True))
            + " |"
            for row in self.rows
        ]
        text = [f"### {self.title}", "", head, rule, *body]
        if self.notes:
            text += ["", *self.notes]
        return "\n".join(text)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Table:
        """The table `to_dict` wrote (samples come back from their runs)."""
        columns = [
            Column(c["name"], c["unit"], c.get("statistic", "median")) for c in data["columns"]
        ]
        rows = [[cell_from_json(row[c.name]) for c in columns] for row in data["rows"]]
        return cls(data["title"], columns, rows, list(data["notes"]))

    def to_dict(self) -> dict[str, Any]:
        return {
            "title": self.title,
            "columns": [
                {"name": c.name, "unit": c.unit, "statistic": c.statistic} for c in self.columns
            ],
            "rows": [
                {col.name: cell_json(cell) for col, cell in zip(self.columns, row, strict=True)}
                for row in self.rows
            ],
            "notes": self.notes,
        }


@dataclass
class Section:
    """One section's outcome: its tables, the settings it ran with, and how long it took."""

    name: str
    description: str
    tables: list[Table] = field(default_factory=list)
    settings: dict[str, Any] = field(default_factory=dict)
    seconds: float = 0.0

    def to_markdown(self) -> str:
        parts = [f"## {self.name}", "", self.description]
        parts += ["", *(t.to_markdown() + "\n" for t in self.tables)]
        return "\n".join(parts).rstrip() + "\n"

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> Section:
        """The section `to_dict` wrote, e.g. to print a saved run again."""
        tables = [Table.from_dict(t) for t in data["tables"]]
        return cls(data["name"], data["description"], tables, data["settings"], data["seconds"])

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "description": self.description,
            "settings": self.settings,
            "seconds": self.seconds,
            "tables": [t.to_dict() for t in self.tables],
        }


def cell_json(cell: Cell) -> Any:
    """A cell as JSON: a sample becomes {median, min, max, mean, n, runs}."""
    return cell.to_dict() if isinstance(cell, Sample) else cell


def cell_from_json(value: Any) -> Cell:
    """A cell as `cell_json` wrote it."""
    if isinstance(value, dict):
        return Sample.of(value["runs"])
    if value is None or isinstance(value, int | float | str):
        return value
    raise ValueError(f"not a table cell: {value!r}")


def format_cell(cell: Cell, column: Column) -> str:
    """A cell for a Markdown table; a sample as `median [min, max]` when its runs differ."""
    unit = column.unit
    if cell is None:
        return "-"
    if isinstance(cell, str):
        return cell
    if isinstance(cell, Sample):
        text = format_number(cell.mean if column.statistic == "mean" else cell.median, unit)
        if len(cell.runs) > 1 and cell.minimum != cell.maximum:
            low, high = format_number(cell.minimum, unit), format_number(cell.maximum, unit)
            text += f" [{low}, {high}]"
        return text
    return format_number(float(cell), unit)


def format_number(value: float, unit: Unit) -> str:
    if unit == "share":
        return f"{value:.1%}"
    if unit == "mib":
        return f"{value:,.0f} MiB"
    if unit == "seconds":
        if value < 1e-3:
            return f"{value * 1e6:.0f} µs"
        if value < 1:
            return f"{value * 1e3:.1f} ms"
        return f"{value:.2f} s"
    if unit == "count":
        return f"{value:,.0f}"
    return f"{value:g}"
