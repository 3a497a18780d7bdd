"""Batches go in by bulk insert and come back exactly, in upload order."""

from __future__ import annotations

import uuid

from sqlalchemy import Engine

from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.detections import Detections
from roadlink.db import repository
from roadlink.db.engine import make_session_factory, transaction
from roadlink.db.json_columns import BatchSelection, WindowSelection
from roadlink.simulation import preset, simulate


def _store(engine: Engine, *batches: Detections) -> tuple[uuid.UUID, list[uuid.UUID]]:
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


def test_a_batch_comes_back_exactly_as_stored(engine: Engine) -> None:
    detections = simulate(
        preset("large", miss_probability=0.1, false_alarm_rate=0.1), seed=3
    ).detections
    deployment_id, (batch_id,) = _store(engine, detections)
    factory = make_session_factory(engine)
    with factory() as session:
        loaded = repository.load_detections(
            session, deployment_id=deployment_id, selection=BatchSelection((batch_id,))
        )
        batch = repository.get_batch(session, batch_id=batch_id)
    assert batch is not None and batch.n_detections == len(detections)
    assert batch.n_labelled == int(detections.labelled.sum())
    # Bit-for-bit: the CSV of what came back equals the CSV of what went in.
    assert write_detections_csv(loaded) == write_detections_csv(detections)


def test_a_time_window_spans_batches_and_keeps_reused_ids_apart(engine: Engine) -> None:
    text = "position,velocity,timestamp\n0,30,1\n100,30,4.3\n0,40,10\n100,40,12.5\n"
    first = read_detections_csv(text)
    second = read_detections_csv(text.replace("\n0,", "\n200,", 1))  # same ids d1..d4
    deployment_id, batch_ids = _store(engine, first, second)
    factory = make_session_factory(engine)
    with factory() as session:
        window = repository.load_detections(
            session, deployment_id=deployment_id, selection=WindowSelection(2.0, 12.5)
        )
        count = repository.count_selected_detections(
            session, deployment_id=deployment_id, selection=WindowSelection(2.0, 12.5)
        )
    # [2, 12.5): 4.3 and 10 from each batch.
    assert sorted(window.timestamp.tolist()) == [4.3, 4.3, 10.0, 10.0]
    assert count == (4, 2)
    assert len(set(window.detection_id.tolist())) == 4
    owners = [d.split(":")[0] for d in window.detection_id]
    # Qualified by batch, and in upload order: the first batch's detections, then the second's.
    assert owners == [str(batch_ids[0])] * 2 + [str(batch_ids[1])] * 2
