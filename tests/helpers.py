"""Plain helpers that the tests share: building request bodies, checking problem details,
counting rows. Fixtures live in conftest.py files; these are imported like any module."""

from __future__ import annotations

import dataclasses
import uuid
from collections.abc import Callable
from datetime import UTC, datetime
from pathlib import Path
from typing import Any

import numpy as np
from sqlalchemy import Engine, func, select

from roadlink.association.csvio import read_detections_csv
from roadlink.association.detections import Detections
from roadlink.association.fast_csv import fast_detections
from roadlink.db import repository
from roadlink.db.detection_blocks import Block
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.json_columns import BatchSelection
from roadlink.db.models import Base, DetectionBlock, Job, JobState

MakeKey = Callable[..., str]
"""The `make_key` fixture: (scope, *deployment ids) -> a new API key."""

EnqueueJob = Callable[..., uuid.UUID]
"""The queue tests' `enqueue` fixture: enqueue a job over a stored batch, return its id."""


def detection_rows(detections: Detections) -> list[dict[str, Any]]:
    """Detections as the JSON batch body lists them (with a key for each feature some
    detection reports, null where this one does not)."""
    d = detections
    features = {name: d.feature_values(name) for name in d.features}
    return [
        {
            "position": float(d.position[i]),
            "velocity": float(d.velocity[i]),
            "timestamp": float(d.timestamp[i]),
            "sensor_id": d.sensor_id[i],
            "detection_id": d.detection_id[i],
            "target": d.target[i],
            **{name: values[i] for name, values in features.items()},
        }
        for i in range(len(d))
    ]


def fast_read(text: str | bytes) -> Detections:
    """Detection CSV read by the fast path (polars), as a large file is read: its ids and labels
    polars' columns (`Detections.parsed_texts`). `read_detections_csv` reads a small text by the
    exact reader where polars is not loaded yet (`csvio.SMALL_BYTES`)."""
    read = fast_detections(text.encode() if isinstance(text, str) else text)
    assert read is not None, "not a plain, valid file: the fast path declined it"
    return read


def with_features(detections: Detections, *, lane_sensors: int | None = None) -> Detections:
    """The detections with the three detector features, each target's own (drawn from its
    label, so that a target's detections agree), as real detectors report them: a truck every
    third target, lanes only from the first `lane_sensors` sensors along the road (all when
    None), and no length or class for false alarms' odd rows (mixed reporting)."""
    d = detections
    labels = [str(t) for t in d.target.tolist()]
    rank = {label: k for k, label in enumerate(sorted(set(labels)))}
    sensors = list(dict.fromkeys(d.sensor_id[np.argsort(d.position, kind="stable")].tolist()))
    with_lanes = set(sensors[:lane_sensors] if lane_sensors is not None else sensors)
    truck = [rank[label] % 3 == 0 for label in labels]
    odd = [label == "clutter" and i % 2 == 1 for i, label in enumerate(labels)]
    return Detections.from_columns(
        d.position,
        d.velocity,
        d.timestamp,
        sensor_id=d.sensor_id.tolist(),
        detection_id=d.detection_id.tolist(),
        target=d.target.tolist(),
        lane=[
            rank[label] % 3 if sensor in with_lanes else None
            for label, sensor in zip(labels, d.sensor_id.tolist(), strict=True)
        ],
        length=[
            None if skip else (12.0 if big else 4.0) + 0.1 * (rank[label] % 7)
            for label, big, skip in zip(labels, truck, odd, strict=True)
        ],
        vehicle_class=[
            None if skip else ("truck" if big else "car")
            for big, skip in zip(truck, odd, strict=True)
        ],
    )


def store_batches(engine: Engine, *batches: Detections) -> tuple[uuid.UUID, list[uuid.UUID]]:
    """Store the batches in a new deployment, through the repository; its id and theirs."""
    factory = make_session_factory(engine)
    with transaction(factory) as session:
        deployment = repository.create_deployment(session, name="road", sensors=None)
        ids = [
            repository.insert_batch(
                session, deployment_id=deployment.id, detections=d, source="json"
            ).id
            for d in batches
        ]
    return deployment.id, ids


def post_csv_batch(
    client: Any, deployment_id: str, text: str, *, request_id: str | None = None, **params: str
) -> dict[str, Any]:
    """Post a CSV batch to the deployment (with `params` in the query, e.g. associator=...,
    and `request_id` as X-Request-ID); the batch as created (201), with its job in `job` when
    one was asked for."""
    headers = {"content-type": "text/csv"}
    if request_id is not None:
        headers["X-Request-ID"] = request_id
    posted = client.post(
        f"/v1/deployments/{deployment_id}/batches", content=text, headers=headers, params=params
    )
    assert posted.status_code == 201, posted.text
    return dict(posted.json())


def unsaved_job(**values: Any) -> Job:
    """A job as the database would hand it back (queued, over one batch of a deployment),
    never stored, with `values` changed: for what reads a job, not what stores it."""
    defaults: dict[str, Any] = {
        "id": uuid.uuid4(),
        "deployment_id": uuid.uuid4(),
        "selection": BatchSelection((uuid.uuid4(),)),
        "associator": "kmeans",
        "params": {},
        "state": JobState.QUEUED,
        "progress": 0.0,
        "attempts": 0,
        "max_attempts": 3,
        "created_at": datetime(2026, 1, 1, tzinfo=UTC),
    }
    return Job(**{**defaults, **values})


def assert_problem(response: Any, status: int) -> dict[str, Any]:
    """The response is problem details with this status; returns its body."""
    assert response.status_code == status, response.text
    assert response.headers["content-type"].startswith("application/problem+json")
    body = dict(response.json())
    assert body["status"] == status and body["title"] and body["detail"]
    return body


def bearer(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


def row_counts(engine: Engine) -> dict[str, int]:
    """The number of rows in every table of the schema, and under "detection" the number of
    detections stored (in every batch's block)."""
    with engine.connect() as connection:
        counts = {
            name: int(connection.scalar(select(func.count()).select_from(table)) or 0)
            for name, table in Base.metadata.tables.items()
        }
    return counts | {"detection": stored_detections(engine)}


def stored_detections(engine: Engine) -> int:
    """How many detections the database holds: the sizes of the stored blocks, as read."""
    with engine.connect() as connection:
        blocks = connection.scalars(select(DetectionBlock.data)).all()
    return sum(Block.parse(bytes(data)).n for data in blocks)


def in_hours(d: Detections) -> Detections:
    """The same detections timed in hours, with positions in km and speeds in km/h."""
    return Detections(
        d.position / 1000.0,
        d.velocity * 3.6,
        d.timestamp / 3600.0,
        d.sensor_id,
        d.detection_id,
        d.target,
    )


def lane_queue(seed: int = 0) -> Detections:
    """Two lanes crawling past three sensors 200 m apart, first in first out in each lane, no
    lane changes, lanes and lengths (7 % error) reported: each lane's travel time drifts slowly
    (40-80 s a segment, 10-25 headways), and only a 300 s window is kept, so each sensor sees
    vehicles that the one before it saw before the window opened."""
    rng = np.random.default_rng(seed)
    gap = 200.0
    rows: list[tuple[float, float, float, str, int, float]] = []
    for lane, headway in ((0, 3.0), (1, 4.0)):
        entries = np.cumsum(rng.uniform(0.6, 1.4, 160) * headway)
        truck = rng.random(entries.size) < 0.1
        length = np.where(
            truck, rng.uniform(8.0, 18.0, entries.size), rng.uniform(3.6, 5.4, entries.size)
        )
        for vehicle, (entry, true_length) in enumerate(zip(entries, length, strict=True)):
            passed = entry
            for sensor in range(3):
                if sensor:
                    passed += 60.0 + 20.0 * np.sin(passed / (100.0 + 20 * lane))
                if 100.0 <= passed <= 400.0:
                    reading = true_length * (1 + 0.07 * rng.standard_normal())
                    speed = max(gap / 60.0 * (1 + 0.2 * rng.standard_normal()), 0.5)
                    rows.append((sensor * gap, speed, passed, f"v{lane}.{vehicle}", lane, reading))
    position, velocity, timestamp, target, lanes, lengths = zip(*rows, strict=True)
    return Detections.from_columns(
        position, velocity, timestamp, target=target, lane=lanes, length=lengths
    )


def travel_times(d: Detections, a: float, b: float) -> np.ndarray:
    """Each vehicle's travel time from the sensor at `a` to the one at `b`."""
    at_a = {t: time for t, time, p in zip(d.target, d.timestamp, d.position, strict=True) if p == a}
    return np.array(
        [
            time - at_a[t]
            for t, time, p in zip(d.target, d.timestamp, d.position, strict=True)
            if p == b and t in at_a
        ]
    )


COMMITTED_DENSE = Path(__file__).parent / "data" / "sumo" / "sumo-dense.csv"
"""SUMO's dense motorway, seed 0 (11 sensors 250 m apart, travel times of about 8 s)."""


def one_sensor_in_km_per_hour(sensor: int = 5) -> Detections:
    """The committed dense case, its `sensor`-th sensor reporting km/h among sensors in m/s."""
    d = read_detections_csv(COMMITTED_DENSE)
    positions = np.unique(d.position)
    return dataclasses.replace(
        d, velocity=d.velocity * np.where(d.position == positions[sensor], 3.6, 1.0)
    )
