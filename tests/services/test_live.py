"""A deployment's live association as the services run it (`roadlink.services.live`): started on
the data stored so far, refused with the field named, stopped and flushed, its status, and the
feed read by cursor with its long-poll wait."""

from __future__ import annotations

import asyncio
import uuid
from collections.abc import Sequence

import pytest
from sqlalchemy import Engine
from sqlalchemy.orm import Session, sessionmaker

from roadlink.db import repository
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.json_columns import Sensor
from roadlink.db.models import LiveVehicle
from roadlink.queue.live_step import run_live_step
from roadlink.services import live
from roadlink.services.problems import ServiceProblem
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.helpers import row_counts
from tests.queue.live_replay import Asked, flush, start, store


@pytest.fixture
def sessions(engine: Engine) -> sessionmaker[Session]:
    return make_session_factory(engine)


@pytest.fixture
def road(sessions: sessionmaker[Session]) -> uuid.UUID:
    """A deployment with two declared sensors, 0 and 900 m."""
    sensors = [Sensor("S1", 0.0), Sensor("S2", 900.0)]
    with transaction(sessions) as session:
        return repository.create_deployment(session, name="live", sensors=sensors).id


def _refused(
    sessions: sessionmaker[Session], call: object, *args: object, **kw: object
) -> ServiceProblem:
    with sessions() as session, pytest.raises(ServiceProblem) as raised:
        call(session, *args, **kw)  # type: ignore[operator]
    return raised.value


def test_starting_takes_the_data_stored_so_far_and_the_declared_road(
    sessions: sessionmaker[Session], settings: Settings, road: uuid.UUID
) -> None:
    d = simulate(preset("small"), seed=2).detections
    store(sessions, settings, road, d)
    start(sessions, road, lateness=7.0)
    with sessions() as session:
        status = live.live_status(live.require_live(session, road))
    assert status.state == "running" and status.lateness == 7.0
    assert status.data_clock == pytest.approx(float(d.timestamp.max()))
    assert status.pending and status.step_clock is None and status.lag is None
    with sessions() as session:
        assert live.require_live(session, road).road_end == 900.0


def test_refusals_name_what_is_wrong_and_change_nothing(
    sessions: sessionmaker[Session], engine: Engine, road: uuid.UUID
) -> None:
    before = row_counts(engine)
    unknown = uuid.uuid4()
    asked = Asked()
    assert (
        _refused(sessions, live.start_live, deployment_id=unknown, asked=asked, lateness=1.0).status
        == 404
    )
    bad = _refused(sessions, live.start_live, deployment_id=road, asked=Asked("nope"), lateness=1.0)
    assert bad.status == 422 and bad.errors[0].field == "associate.associator"
    late = _refused(sessions, live.start_live, deployment_id=road, asked=asked, lateness=-1.0)
    assert late.status == 422 and late.errors[0].field == "lateness"
    assert _refused(sessions, live.require_live, road).status == 404
    assert _refused(sessions, live.stop_live, deployment_id=road).status == 404
    assert _refused(sessions, live.flush_live, deployment_id=road).status == 404
    assert (
        _refused(sessions, live.read_vehicles, deployment_id=unknown, after=0, limit=1).status
        == 404
    )
    assert row_counts(engine) == before


def test_stopped_it_cannot_be_flushed_and_stopping_again_changes_nothing(
    sessions: sessionmaker[Session], road: uuid.UUID
) -> None:
    start(sessions, road, lateness=1.0)
    with sessions() as session:
        assert live.stop_live(session, deployment_id=road).active is False
        assert live.stop_live(session, deployment_id=road).active is False
    problem = _refused(sessions, live.flush_live, deployment_id=road)
    assert problem.status == 409 and "stopped" in problem.detail


@pytest.mark.parametrize("cursor", ["abc", "-1", "1.5", "٣", "1" * 19])
def test_a_cursor_the_service_did_not_give_is_a_422_naming_after(cursor: str) -> None:
    with pytest.raises(ServiceProblem) as raised:
        live.parse_cursor(cursor)
    assert raised.value.status == 422 and raised.value.errors[0].field == "after"


def test_no_cursor_is_the_beginning() -> None:
    assert live.parse_cursor(None) == live.parse_cursor("") == 0
    assert live.parse_cursor("42") == 42


def test_the_feed_and_the_plot_data_after_a_flush(
    sessions: sessionmaker[Session], settings: Settings, road: uuid.UUID
) -> None:
    start(sessions, road, lateness=5.0)
    with sessions() as session:
        assert live.recent_result(session, deployment_id=road, vehicles=3) is None
    d = simulate(preset("large", n_targets=4), seed=5).detections
    store(sessions, settings, road, d)
    flush(sessions, road)
    while run_live_step(sessions, worker_id="w1", lease_seconds=30.0):
        pass
    with sessions() as session:
        vehicles = live.read_vehicles(session, deployment_id=road, after=0, limit=100)
        assert [v.vehicle_id for v in vehicles] == ["V1", "V2", "V3", "V4"]
        page = live.read_vehicles(session, deployment_id=road, after=vehicles[1].seq, limit=1)
        assert [v.vehicle_id for v in page] == ["V3"]
        document = live.vehicle_document(vehicles[0])
        assert document["cursor"] == str(vehicles[0].seq) and document["final"] is True
        times = [x["timestamp"] for x in document["detections"]]
        assert times == sorted(times) and len(times) == 10
        result = live.recent_result(session, deployment_id=road, vehicles=3)
    assert result is not None and result.n_targets == 3  # the last three, each a target


def _feed(pages: list[list[str]]) -> object:
    """A read that answers these pages in turn (vehicle ids standing in for vehicles)."""
    answers = iter(pages)

    async def read() -> Sequence[LiveVehicle]:
        return next(answers)  # type: ignore[return-value]

    return read


async def _gone() -> bool:
    return True


async def _here() -> bool:
    return False


def test_a_wait_returns_the_first_vehicles_published() -> None:
    found = asyncio.run(
        live.wait_for_vehicles(
            _feed([[], [], ["V1"]]),  # type: ignore[arg-type]
            wait=60.0,
            max_wait=60.0,
            client_gone=_here,
        )
    )
    assert found == ["V1"]


def test_a_wait_of_zero_answers_at_once_and_a_client_that_left_is_a_408() -> None:
    empty = asyncio.run(
        live.wait_for_vehicles(_feed([[]]), wait=0.0, max_wait=60.0, client_gone=_here)  # type: ignore[arg-type]
    )
    assert empty == []
    with pytest.raises(ServiceProblem) as raised:
        asyncio.run(
            live.wait_for_vehicles(
                _feed([[], []]),  # type: ignore[arg-type]
                wait=60.0,
                max_wait=60.0,
                client_gone=_gone,
            )
        )
    assert raised.value.status == 408
