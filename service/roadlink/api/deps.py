"""Dependencies shared by the routers: settings and a database session per request."""

from __future__ import annotations

from collections.abc import AsyncIterator
from typing import Annotated

from fastapi import Depends, Request
from sqlalchemy.orm import Session, sessionmaker
from starlette.concurrency import run_in_threadpool

from roadlink.settings import Settings

# The two that only read the app's state are coroutines: FastAPI runs a plain function dependency
# in its thread pool, a hop (and on a busy host a wait for a core) per request for an attribute.


async def get_settings(request: Request) -> Settings:
    """The app's settings."""
    settings: Settings = request.app.state.settings
    return settings


async def get_session_factory(request: Request) -> sessionmaker[Session]:
    """The app's session factory (for handlers that run several transactions)."""
    factory: sessionmaker[Session] = request.app.state.sessions
    return factory


async def get_session(request: Request) -> AsyncIterator[Session]:
    """A session for one request. Handlers that write commit before they answer; anything left
    uncommitted (a handler that raised) is rolled back, so a rejected request leaves no trace.

    A coroutine too: making a session touches no database, and closing one that holds no
    transaction (every handler that committed) returns nothing to the pool; only a session left
    in a transaction, whose close rolls it back, is closed in the thread pool. As a plain
    generator, every request paid two thread-pool hops, on entry and on exit."""
    factory: sessionmaker[Session] = request.app.state.sessions
    session = factory()
    try:
        yield session
    finally:
        if session.in_transaction():
            await run_in_threadpool(session.close)
        else:
            session.close()


SettingsDep = Annotated[Settings, Depends(get_settings)]
SessionDep = Annotated[Session, Depends(get_session)]
SessionFactoryDep = Annotated[sessionmaker[Session], Depends(get_session_factory)]
