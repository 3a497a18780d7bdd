from typer.testing import CliRunner

from roadlink.cli import app
from roadlink.configuration import env_example, markdown_table

runner = CliRunner()


def test_config_prints_the_markdown_table_by_default() -> None:
    result = runner.invoke(app, ["config"])
    assert result.exit_code == 0, result.output
    assert result.output == markdown_table()


def test_config_prints_the_env_example() -> None:
    result = runner.invoke(app, ["config", "--format", "env"])
    assert result.exit_code == 0, result.output
    assert result.output == env_example()
    assert "# ROADLINK_DATABASE_URL=sqlite:///./roadlink.db" in result.output
