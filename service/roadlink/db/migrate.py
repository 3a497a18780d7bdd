"""Running the Alembic migrations, from a source checkout or from an installed wheel.

In a checkout the scripts live in `migrations/` beside `alembic.ini`; the wheel carries the same
directory as `roadlink/_migrations` (pyproject force-includes it).
"""

from __future__ import annotations

from pathlib import Path

from alembic import command
from alembic.config import Config
from alembic.runtime.migration import MigrationContext
from alembic.script import ScriptDirectory
from sqlalchemy import Engine

PACKAGE_DIR = Path(__file__).resolve().parent.parent
# service/roadlink/ in a checkout: the repository root is two folders up.
CHECKOUT_MIGRATIONS = PACKAGE_DIR.parent.parent / "migrations"


def migrations_directory() -> Path:
    """Where the migration scripts are: the wheel's copy, else the checkout's."""
    for candidate in (PACKAGE_DIR / "_migrations", CHECKOUT_MIGRATIONS):
        if (candidate / "env.py").is_file():
            return candidate
    raise FileNotFoundError(
        f"no Alembic migrations found in {PACKAGE_DIR / '_migrations'} or {CHECKOUT_MIGRATIONS}"
    )


def alembic_config(database_url: str) -> Config:
    """An Alembic configuration for `database_url` that needs no alembic.ini."""
    config = Config()
    config.set_main_option("script_location", str(migrations_directory()))
    # ConfigParser interpolation would read '%' in passwords as a reference.
    config.set_main_option("sqlalchemy.url", database_url.replace("%", "%%"))
    return config


def upgrade_to_head(database_url: str) -> None:
    """Bring the schema up to the newest migration (a fresh database gets every table)."""
    command.upgrade(alembic_config(database_url), "head")


def head_revision() -> str | None:
    """The newest migration's revision id."""
    return ScriptDirectory.from_config(alembic_config("sqlite://")).get_current_head()


def current_revision(engine: Engine) -> str | None:
    """The revision the database is at (None when never migrated)."""
    with engine.connect() as connection:
        return MigrationContext.configure(connection).get_current_revision()
