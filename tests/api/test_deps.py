"""The routers' shared dependencies (`api/deps.py`): the app's settings and session factory, and a
session per request that leaves no trace of a handler that raised."""

from __future__ import annotations

import uuid

from fastapi import FastAPI
from fastapi.testclient import TestClient
from sqlalchemy import Engine, select

from roadlink.api.deps import SessionDep, SessionFactoryDep, SettingsDep
from roadlink.db.engine import make_session_factory
from roadlink.db.models import Deployment
from roadlink.settings import Settings


def app_on(engine: Engine, settings: Settings) -> FastAPI:
    app = FastAPI()
    app.state.settings = settings
    app.state.sessions = make_session_factory(engine)

    @app.get("/settings")
    def read_settings(settings: SettingsDep) -> int:
        return settings.max_body_bytes

    @app.post("/deployments/{name}")
    def add(name: str, session: SessionDep, factory: SessionFactoryDep, commit: bool) -> str:
        assert factory is app.state.sessions
        session.add(Deployment(id=uuid.uuid4(), name=name))
        session.flush()  # written, but only a commit keeps it
        if not commit:
            raise RuntimeError("the handler failed after writing")
        session.commit()
        return name

    return app


def names(engine: Engine) -> list[str]:
    with make_session_factory(engine)() as session:
        return list(session.scalars(select(Deployment.name)))


def test_the_settings_are_the_apps(engine: Engine, settings: Settings) -> None:
    client = TestClient(app_on(engine, settings))
    assert client.get("/settings").json() == settings.max_body_bytes


def test_a_handler_that_raises_leaves_no_trace_and_one_that_commits_keeps_its_writes(
    engine: Engine, settings: Settings
) -> None:
    client = TestClient(app_on(engine, settings), raise_server_exceptions=False)
    assert client.post("/deployments/lost", params={"commit": False}).status_code == 500
    assert client.post("/deployments/kept", params={"commit": True}).status_code == 200
    assert names(engine) == ["kept"]


def test_every_requests_session_gives_its_connection_back(
    engine: Engine, settings: Settings
) -> None:
    """Whether the handler committed, raised after writing, or only read (its transaction still
    open when it returns), the session is closed and its connection back in the pool."""
    app = app_on(engine, settings)

    @app.get("/count")
    def count(session: SessionDep) -> int:
        return len(list(session.scalars(select(Deployment.id))))

    client = TestClient(app, raise_server_exceptions=False)
    before = engine.pool.checkedout()  # type: ignore[attr-defined]
    assert client.post("/deployments/one", params={"commit": True}).status_code == 200
    assert client.post("/deployments/two", params={"commit": False}).status_code == 500
    assert client.get("/count").status_code == 200
    assert engine.pool.checkedout() == before  # type: ignore[attr-defined]
