"""Alembic is the only way the schema changes: the migrations build exactly the models' schema,
and unwind cleanly, on both databases."""

from __future__ import annotations

from pathlib import Path

import pytest
from alembic import command
from alembic.config import Config
from sqlalchemy import inspect

from roadlink.db.engine import make_engine
from roadlink.db.migrate import (
    alembic_config,
    current_revision,
    head_revision,
    migrations_directory,
)
from roadlink.db.models import Base
from tests.databases import BACKENDS

REPO = Path(__file__).resolve().parents[2]


@pytest.mark.parametrize("empty_database_url", BACKENDS, indirect=True)
def test_upgrade_check_downgrade_with_alembic_ini(empty_database_url: str) -> None:
    """`alembic upgrade head`, then `alembic check`, then `alembic downgrade base`, as a
    developer runs them from the checkout."""
    config = Config(str(REPO / "alembic.ini"))
    config.cmd_opts = type("Options", (), {"x": [f"url={empty_database_url}"]})()  # -x url=...
    command.upgrade(config, "head")
    engine = make_engine(empty_database_url)
    assert set(inspect(engine).get_table_names()) >= set(Base.metadata.tables)
    assert current_revision(engine) == head_revision()

    command.check(config)  # raises when the models and the migrations disagree

    command.downgrade(config, "base")
    assert set(inspect(engine).get_table_names()) <= {"alembic_version"}
    assert current_revision(engine) is None
    engine.dispose()


def test_programmatic_config_finds_the_scripts_without_an_ini_file() -> None:
    """`roadlink migrate` builds its configuration in code (an installed wheel has no
    alembic.ini), from the scripts next to the package."""
    config = alembic_config("sqlite://")
    assert Path(config.get_main_option("script_location") or "") == migrations_directory()
    assert (migrations_directory() / "env.py").is_file()
    assert head_revision() is not None
