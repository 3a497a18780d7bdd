"""The fast path of a JSON batch (`api/json_detections.py`): msgspec's typed rows give the
detections the exact path gives, and every body the exact path would refuse (or read otherwise)
is left to it, so that its problems are named as before."""

from __future__ import annotations

import json
from typing import Any

import numpy as np
import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadlink.api.errors import ApiProblem
from roadlink.api.ingest import _exact_json_batch, _fast_json_batch, parse_json_batch
from roadlink.api.json_detections import decode_rows, row_columns
from roadlink.association.detections import COLUMNS, Detections
from roadlink.db.json_columns import Sensor
from roadlink.simulation import preset, simulate
from tests.helpers import detection_rows, with_features

SENSORS = [Sensor("S1", 0.0), Sensor("S2", 100.0)]


def assert_same(got: Detections, want: Detections) -> None:
    for name in COLUMNS:
        a, b = getattr(got, name), getattr(want, name)
        assert a.dtype == b.dtype and a.shape == b.shape, name
        if a.dtype.kind == "f":
            assert np.array_equal(a, b, equal_nan=True), name
            assert np.array_equal(np.signbit(a), np.signbit(b)), name
        else:
            assert a.tolist() == b.tolist(), name
            assert [type(v) for v in a.tolist()] == [type(v) for v in b.tolist()], name


def outcome(call: Any, *args: Any) -> Any:
    """What a parse gives: its detections and association, or its problem's whole content."""
    try:
        return call(*args)
    except ApiProblem as problem:
        return (problem.status, problem.detail, problem.errors)


def assert_same_outcome(body: bytes, sensors: list[Sensor] | None = None, limit: int = 100):
    fast, exact = (
        outcome(parse_json_batch, body, sensors, limit),
        outcome(_exact_json_batch, body, sensors, limit),
    )
    if isinstance(exact, tuple) and isinstance(exact[0], Detections):
        assert isinstance(fast, tuple) and isinstance(fast[0], Detections)
        assert_same(fast[0], exact[0])
        assert fast[1] == exact[1]
    else:
        assert fast == exact


@pytest.mark.parametrize("features", [False, True])
def test_a_simulated_batch_reads_as_the_exact_path_reads_it(features: bool) -> None:
    detections = simulate(preset("small", false_alarm_rate=0.2), seed=3).detections
    if features:
        detections = with_features(detections, lane_sensors=4)
    body = orjson.dumps(
        {"detections": detection_rows(detections), "associate": {"associator": "kmeans"}}
    )
    assert _fast_json_batch(body, None, 1000) is not None  # the fast path read it
    assert_same_outcome(body, limit=1000)


def test_declared_sensors_fill_and_check_on_the_fast_path_too() -> None:
    rows = [
        {"position": 0.0, "velocity": 30.0, "timestamp": 1.0},
        {"position": 100, "velocity": 31.5, "timestamp": 4.3, "sensor_id": "S2"},
    ]
    body = json.dumps({"detections": rows}).encode()
    detections, _ = parse_json_batch(body, SENSORS, 10)
    assert detections.sensor_id.tolist() == ["S1", "S2"]
    assert_same_outcome(body, SENSORS)
    wrong = json.dumps({"detections": [{**rows[1], "sensor_id": "S1"}]}).encode()
    assert _fast_json_batch(wrong, SENSORS, 10) is None
    assert_same_outcome(wrong, SENSORS)


@pytest.mark.parametrize(
    "body",
    [
        b"{",
        b"\xef\xbb\xbf" + b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1}]}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1, "sensor_id": "\xff"}]}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1, "target": "\\ud800"}]}',
        b'{"detections": [{"position": 1e400, "velocity": 1, "timestamp": 1}]}',
        b'{"detections": [{"position": true, "velocity": 1, "timestamp": 1}]}',
        b'{"detections": [{"position": "0", "velocity": 1, "timestamp": 1}]}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1, "lane": false}]}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1, "colour": "red"}]}',
        b'{"detections": [{"position": 0, "velocity": 1}]}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": null}]}',
        b'{"detections": [[0, 1, 1]]}',
        b'{"detections": []}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1}], "more": 1}',
        b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1}], "associate": 5}',
        b"[]",
    ],
)
def test_bodies_the_exact_path_refuses_are_left_to_it(body: bytes) -> None:
    assert _fast_json_batch(body, None, 10) is None
    assert isinstance(outcome(parse_json_batch, body, None, 10)[0], int)  # a problem
    assert_same_outcome(body, limit=10)


@pytest.mark.parametrize(
    "row",
    [
        {"velocity": -1.0},  # the core refuses it
        {"timestamp": 10**13},  # beyond the magnitude limit
        {"position": 10**400},  # beyond any float
        {"lane": 1.5},
        {"lane": 2.0},  # a whole number written as a float: a lane
        {"length": 0},
        {"length": 1e13},
        {"vehicle_class": " car "},
        {"vehicle_class": "x" * 40},
        {"sensor_id": " S1"},
        {"detection_id": ""},
        {"target": "  "},
    ],
)
def test_values_read_or_refused_as_the_exact_path_reads_or_refuses_them(row: dict) -> None:
    rows = [{"position": 0, "velocity": 20, "timestamp": 1, **row}]
    rows.append({"position": 100, "velocity": 20, "timestamp": 6, "detection_id": "x"})
    assert_same_outcome(json.dumps({"detections": rows}).encode())


def test_repeated_keys_read_the_last_as_orjson_does() -> None:
    body = b'{"detections": [{"position": 0, "position": 5, "velocity": 1, "timestamp": 1}]}'
    detections, _ = parse_json_batch(body, None, 10)
    assert detections.position.tolist() == [5.0]
    assert_same_outcome(body)


def test_too_many_rows_are_left_to_the_exact_path_which_names_the_limit() -> None:
    body = json.dumps({"detections": [{"position": 0, "velocity": 1, "timestamp": 1}] * 3})
    assert _fast_json_batch(body.encode(), None, 2) is None
    assert "past the 2" in outcome(parse_json_batch, body.encode(), None, 2)[1]


def test_row_columns_leave_out_the_features_no_row_reports() -> None:
    decoded = decode_rows(b'{"detections": [{"position": 0, "velocity": 1, "timestamp": 1}]}')
    assert decoded is not None
    columns = row_columns(decoded[0])
    assert columns["lane"] is None and columns["length"] is None
    assert columns["vehicle_class"] is None
    assert decoded[1] is None  # no association asked for


json_values = st.one_of(
    st.none(),
    st.booleans(),
    st.integers(min_value=-(10**15), max_value=10**15),
    st.floats(allow_nan=False, allow_infinity=False),
    st.sampled_from([0, 1, 2, 255, 256, 4.5, 100.0, 100.5, -1]),
    st.text(max_size=4),
    st.sampled_from(["S1", "car", " car", "", "A"]),
    st.lists(st.integers(), max_size=2),
)
fields = st.sampled_from([*COLUMNS, "colour"])


@settings(max_examples=300, deadline=None)
@given(
    st.lists(
        st.dictionaries(fields, json_values, max_size=9).map(
            lambda extra: {"position": 0, "velocity": 20, "timestamp": 1, **extra}
        ),
        min_size=1,
        max_size=5,
    )
)
def test_any_rows_read_or_refused_as_the_exact_path_does(rows: list[dict[str, Any]]) -> None:
    """Rows of any JSON values in any field: the detections, or the problems, are the exact
    path's."""
    assert_same_outcome(json.dumps({"detections": rows}).encode())
