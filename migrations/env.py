"""Alembic environment: the target schema is roadlink.db.models; the URL comes from the config
(set by `roadlink migrate`), `-x url=...`, or ROADLINK_DATABASE_URL."""

from __future__ import annotations

from logging.config import fileConfig

from alembic import context
from sqlalchemy import pool

from roadlink.db.drivers import driver_for
from roadlink.db.engine import make_engine
from roadlink.db.models import Base
from roadlink.settings import Settings

config = context.config
if config.config_file_name is not None:
    fileConfig(config.config_file_name, disable_existing_loggers=False)


def database_url() -> str:
    given = context.get_x_argument(as_dictionary=True).get("url")
    return given or config.get_main_option("sqlalchemy.url") or Settings().database_url


def run_migrations_offline() -> None:
    context.configure(
        url=database_url(),
        target_metadata=Base.metadata,
        literal_binds=True,
        render_as_batch=True,
    )
    with context.begin_transaction():
        context.run_migrations()


def run_migrations_online() -> None:
    url = database_url()
    driver = driver_for(url)  # what differs between the databases, migrations included
    engine = make_engine(url, poolclass=pool.NullPool)
    with engine.connect() as connection, driver.migrating(connection):
        context.configure(
            connection=connection,
            target_metadata=Base.metadata,
            render_as_batch=driver.rebuilds_tables,
            compare_type=True,
        )
        with context.begin_transaction():
            driver.lock_migrations(connection)
            context.run_migrations()
    engine.dispose()


if context.is_offline_mode():
    run_migrations_offline()
else:
    run_migrations_online()
