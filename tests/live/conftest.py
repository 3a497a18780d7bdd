"""Fixtures for the live association's tests: sessions on the test database, and a
deployment."""

from __future__ import annotations

import uuid

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db import repository
from roadlink.db.engine import make_session_factory, transaction


@pytest.fixture
def sessions(engine: Engine) -> sessionmaker[Session]:
    return make_session_factory(engine)


@pytest.fixture
def road(sessions: sessionmaker[Session]) -> uuid.UUID:
    """A deployment without declared sensors."""
    with transaction(sessions) as session:
        return repository.create_deployment(session, name="live road", sensors=None).id
