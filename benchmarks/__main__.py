"""`python -m benchmarks [--quick] [--only SECTION ...] [--json PATH]`: run, print, save."""

from __future__ import annotations

import argparse
import datetime
import json
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from benchmarks.machine import describe_machine, machine_line
from benchmarks.report import Section
from benchmarks.sections import SECTIONS

DEFAULT_JSON = Path(__file__).resolve().parent / "results" / "latest.json"


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    parser = argparse.ArgumentParser(
        prog="python -m benchmarks", description="roadlink's benchmark suite."
    )
    parser.add_argument(
        "--quick", action="store_true", help="small sizes, fewer repeats: under two minutes"
    )
    parser.add_argument(
        "--only",
        nargs="+",
        choices=list(SECTIONS),
        metavar="SECTION",
        help=f"run only these sections (of: {', '.join(SECTIONS)})",
    )
    parser.add_argument(
        "--json", type=Path, default=DEFAULT_JSON, help=f"where to write results ({DEFAULT_JSON})"
    )
    parser.add_argument(
        "--render",
        type=Path,
        metavar="JSON",
        help="print the tables of a saved results file instead of running anything",
    )
    return parser.parse_args(argv)


def run_sections(names: Sequence[str], quick: bool) -> list[Section]:
    """Run the named sections in order, timing each; progress goes to stderr."""
    sections = []
    for name in names:
        print(f"running {name} ...", file=sys.stderr, flush=True)
        start = time.perf_counter()
        section = SECTIONS[name](quick)
        section.seconds = time.perf_counter() - start
        print(f"{name} took {section.seconds:.1f} s", file=sys.stderr, flush=True)
        sections.append(section)
    return sections


def results_document(
    sections: Sequence[Section], quick: bool, started: datetime.datetime
) -> dict[str, Any]:
    """Everything measured, with when and where: the JSON the suite writes."""
    return {
        "date": started.isoformat(timespec="seconds"),
        "mode": "quick" if quick else "full",
        "machine": describe_machine(),
        "sections": [s.to_dict() for s in sections],
    }


def render(document: dict[str, Any]) -> str:
    """A results document as Markdown: date, mode, machine, then every section's tables."""
    parts = [
        f"# roadlink benchmarks ({document['mode']}), {document['date']}",
        "",
        machine_line(document["machine"]),
        "",
    ]
    parts += [Section.from_dict(s).to_markdown() for s in document["sections"]]
    return "\n".join(parts)


def main(argv: Sequence[str] | None = None) -> None:
    args = parse_args(argv)
    if args.render:
        if not args.render.is_file():
            sys.exit(f"no results file at {args.render}")
        print(render(json.loads(args.render.read_text())))
        return
    started = datetime.datetime.now(datetime.UTC)
    sections = run_sections(args.only or list(SECTIONS), args.quick)
    document = results_document(sections, args.quick, started)
    print(render(document))
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(document, indent=2) + "\n")
    print(f"results written to {args.json}", file=sys.stderr)


if __name__ == "__main__":
    main()
