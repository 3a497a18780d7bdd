"""The typed values of the JSON columns read back as they were written, from the JSON the
columns have always held (`roadlink.db.json_columns`)."""

from __future__ import annotations

import uuid

import pytest

from roadlink.db.json_columns import (
    BatchSelection,
    SelectionType,
    Sensor,
    SensorsType,
    WindowSelection,
    selection_from_json,
)


def test_a_batch_named_twice_is_selected_once_in_the_order_asked() -> None:
    a, b = uuid.uuid4(), uuid.uuid4()
    assert BatchSelection.of([b, a, b]).batch_ids == (b, a)


@pytest.mark.parametrize(
    "selection",
    [
        BatchSelection((uuid.uuid4(), uuid.uuid4())),
        WindowSelection(1.5, None),
        WindowSelection(None, None),
    ],
    ids=["batches", "window from", "everything"],
)
def test_a_selection_reads_back_as_written(selection: BatchSelection | WindowSelection) -> None:
    column = SelectionType()
    stored = column.process_bind_param(selection, dialect=None)  # type: ignore[arg-type]
    assert column.process_result_value(stored, dialect=None) == selection  # type: ignore[arg-type]


def test_selections_read_the_json_they_always_had() -> None:
    batch = uuid.uuid4()
    assert selection_from_json({"batch_ids": [str(batch)]}) == BatchSelection((batch,))
    assert selection_from_json({"start": 0.0, "end": 10.0}) == WindowSelection(0.0, 10.0)
    assert selection_from_json({}) == WindowSelection(None, None)


def test_sensors_are_stored_in_road_order_as_plain_json() -> None:
    column = SensorsType()
    sensors = [Sensor("S1", 0.0), Sensor("S2", 250.0)]
    stored = column.process_bind_param(sensors, dialect=None)  # type: ignore[arg-type]
    assert stored == [{"sensor_id": "S1", "position": 0.0}, {"sensor_id": "S2", "position": 250.0}]
    assert column.process_result_value(stored, dialect=None) == sensors  # type: ignore[arg-type]
    assert column.process_bind_param(None, dialect=None) is None  # type: ignore[arg-type]
