"""Engines and transactions (`roadlink.db.engine`)."""

from __future__ import annotations

from pathlib import Path

import pytest
from sqlalchemy import Engine, func, select

from roadlink.db import repository
from roadlink.db.engine import check_writable, make_engine, make_session_factory, transaction
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.models import Deployment


class Refused(Exception):
    """Raised inside a transaction to roll it back."""


def _deployments(engine: Engine) -> int:
    with engine.connect() as connection:
        return int(connection.scalar(select(func.count()).select_from(Deployment)) or 0)


def test_a_transaction_commits_on_success_and_rolls_back_on_any_exception(engine: Engine) -> None:
    sessions = make_session_factory(engine)
    with pytest.raises(Refused), transaction(sessions) as session:
        repository.create_deployment(session, name="road", sensors=None)
        raise Refused
    assert _deployments(engine) == 0
    with transaction(sessions) as session:
        deployment = repository.create_deployment(session, name="road", sensors=None)
    assert _deployments(engine) == 1
    assert deployment.name == "road", "loaded objects stay usable after the commit"


def test_a_database_that_takes_writes_passes_the_check(engine: Engine) -> None:
    check_writable(engine)


def test_a_read_only_database_fails_the_check(tmp_path: Path) -> None:
    path = tmp_path / "x.db"
    upgrade_to_head(f"sqlite:///{path}")
    engine = make_engine(f"sqlite:///file:{path}?mode=ro&uri=true")
    try:
        with pytest.raises(Exception, match="readonly"):
            check_writable(engine)
    finally:
        engine.dispose()
