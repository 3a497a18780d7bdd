"""The configuration reference (docs/configuration.md, .env.example) is generated from Settings:
these tests fail when a setting is added, renamed or redescribed without regenerating it."""

from __future__ import annotations

import os
from pathlib import Path

from roadlink.configuration import (
    TABLE_END,
    TABLE_START,
    env_example,
    markdown_table,
    setting_references,
)
from roadlink.settings import Settings

ROOT = Path(__file__).resolve().parent.parent


def test_every_setting_is_in_the_reference_with_a_meaning() -> None:
    variables = [s.variable for s in setting_references()]
    assert variables == [f"ROADLINK_{name.upper()}" for name in Settings.model_fields]
    assert all(s.meaning for s in setting_references()), "a setting has no description"


def test_docs_configuration_holds_the_generated_table() -> None:
    text = (ROOT / "docs" / "configuration.md").read_text()
    committed = text[text.index(TABLE_START) : text.index(TABLE_END) + len(TABLE_END)] + "\n"
    assert committed == markdown_table(), (
        "docs/configuration.md is stale: regenerate its table with `roadlink config`"
    )


def test_env_example_is_generated() -> None:
    assert (ROOT / ".env.example").read_text() == env_example(), (
        ".env.example is stale: regenerate it with `roadlink config --format env > .env.example`"
    )


def test_env_example_defaults_are_the_settings_defaults(monkeypatch) -> None:
    """Uncommenting every line of .env.example must give the default settings."""
    for name in [n for n in os.environ if n.startswith("ROADLINK_")]:
        monkeypatch.delenv(name)
    uncommented = 0
    for line in env_example().splitlines():
        if line.startswith("# ROADLINK_") and not line.endswith("="):
            name, value = line[2:].split("=", 1)
            monkeypatch.setenv(name, value)
            uncommented += 1
    # All but those without a literal default (the number of workers, the public URL, the
    # heartbeat directory, which is per user, the retention period: unset keeps everything).
    assert uncommented == len(Settings.model_fields) - 4
    defaults = {
        name: field.get_default(call_default_factory=True)
        for name, field in Settings.model_fields.items()
    }
    assert Settings().model_dump() == defaults


def test_the_table_shows_a_computed_default_in_words() -> None:
    (workers,) = [s for s in setting_references() if s.variable == "ROADLINK_WORKERS"]
    assert not workers.literal_default
    assert "| `ROADLINK_WORKERS` | the number of cores |" in markdown_table()
    assert "\n# ROADLINK_WORKERS=\n" in env_example()
