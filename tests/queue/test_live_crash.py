"""Crash safety of the live association with real worker processes: a replay of per-sensor
batches while the worker is SIGKILLed at random points five times and restarted; at the end
every vehicle is in the feed exactly once (by id and final revision), no detection is in two
vehicles, and the accuracy is the offline job's."""

from __future__ import annotations

import multiprocessing
import os
import random
import signal
import time
import uuid

import orjson
import pytest
from sqlalchemy.orm import Session, sessionmaker

from roadlink.association.pipeline import associate
from roadlink.db.engine import make_engine, make_session_factory, transaction
from roadlink.db.live_records import get_live
from roadlink.db.migrate import upgrade_to_head
from roadlink.db.repository import create_deployment
from roadlink.queue.worker import run_worker_process
from roadlink.settings import Settings
from roadlink.simulation import preset, simulate
from tests.databases import BACKENDS
from tests.queue.live_replay import flush, live_score, per_sensor_batches, published, start, store

KILLS = 5


@pytest.fixture
def crash_database(empty_database_url: str) -> str:
    """A database of its own: the worker processes open it themselves."""
    upgrade_to_head(empty_database_url)
    return empty_database_url


def _start_worker(settings: Settings) -> multiprocessing.process.BaseProcess:
    process = multiprocessing.get_context("spawn").Process(
        target=run_worker_process, args=(settings,)
    )
    process.start()
    return process


def _settled(sessions: sessionmaker[Session], road: uuid.UUID) -> bool:
    with sessions() as session:
        live = get_live(session, deployment_id=road)
        assert live is not None
        return (
            live.received == live.processed
            and live.flush_requested == live.flushed
            and live.open_detections == 0
        )


@pytest.mark.slow
@pytest.mark.parametrize("empty_database_url", BACKENDS, indirect=True)
def test_every_vehicle_exactly_once_across_five_sigkills(crash_database: str) -> None:
    settings = Settings(
        database_url=crash_database,
        workers=1,
        lease_seconds=1.0,
        heartbeat_seconds=0.2,
        poll_seconds=0.05,
    )
    engine = make_engine(crash_database)
    sessions = make_session_factory(engine)
    config = preset("large", n_targets=60, start_time_range=(1.0, 300.0))
    d = simulate(config, seed=8).detections
    with transaction(sessions) as session:
        road = create_deployment(session, name="crash road", sensors=None).id
    start(sessions, road, lateness=10.0)
    batches = list(per_sensor_batches(d, 5.0))
    rng = random.Random(18)
    kill_at = sorted(rng.sample(range(len(batches) // 10, len(batches)), KILLS))
    worker = _start_worker(settings)
    kills = 0
    try:
        for k, batch in enumerate(batches):
            store(sessions, settings, road, batch)
            if kill_at and k == kill_at[0]:
                kill_at.pop(0)
                # A random point of the worker's work: mid-step, mid-commit, or idle.
                time.sleep(rng.uniform(0.0, 0.3))
                os.kill(worker.pid or 0, signal.SIGKILL)
                worker.join(10)
                kills += 1
                worker = _start_worker(settings)
        flush(sessions, road)
        deadline = time.monotonic() + 240
        while not _settled(sessions, road):
            assert worker.is_alive(), "the worker died"
            assert time.monotonic() < deadline, "the live association did not settle"
            time.sleep(0.1)
    finally:
        worker.terminate()
        worker.join(10)
        engine.dispose()
    assert kills == KILLS
    vehicles = published(sessions, road)
    ids = [(v.vehicle_id, v.revision) for v in vehicles]
    assert len(ids) == len(set(ids)), "a vehicle was published twice"
    assert [v.vehicle_id for v in vehicles] == [f"V{k + 1}" for k in range(len(vehicles))]
    assert all(v.final for v in vehicles)
    members = [
        (x["batch_id"], x["detection_id"])
        for v in vehicles
        for x in orjson.loads(v.detections_json)
    ]
    assert len(members) == len(set(members)), "a detection is in two vehicles"
    offline = associate(d, "assignment").metrics
    assert offline is not None
    assert live_score(d, vehicles).accuracy >= offline.accuracy - 0.01
