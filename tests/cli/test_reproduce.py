"""`roadlink reproduce` (`cli/reproduce.py`): the paper's comparison, as a table and a chart."""

import json

from typer.testing import CliRunner

from roadlink.cli import app

runner = CliRunner()


def test_reproduce_prints_the_table_and_writes_the_chart(tmp_path):
    chart, table = tmp_path / "chart.png", tmp_path / "table.json"
    result = runner.invoke(
        app,
        [
            "reproduce",
            "--seeds",
            "2",
            "--preset",
            "small",
            "--associator",
            "kmeans++",
            "--plot",
            str(chart),
            "--json",
            str(table),
        ],
    )
    assert result.exit_code == 0, result.output
    assert "| kmeans++ |" in result.stdout and "| kmeans++ (raw) |" in result.stdout
    assert chart.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rows = json.loads(table.read_text())
    assert {(r["associator"], r["backproject"]) for r in rows} == {
        ("kmeans++", True),
        ("kmeans++", False),
    }
    assert all(len(r["accuracies"]) == 2 for r in rows)
