"""The fast CSV path reads a plain, valid file exactly as the exact reader does, and declines
(None) everything else, which the exact reader then reads (and names the problems of)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadlink.association.csvio import read_csv_columns, write_detections_csv
from roadlink.association.detections import COLUMNS, Detections
from roadlink.association.fast_csv import fast_detections
from roadlink.simulation import preset, simulate


def exact(text: str) -> Detections:
    columns = read_csv_columns(text.lstrip("\ufeff"))
    return Detections.from_columns(
        columns["position"] or [],
        columns["velocity"] or [],
        columns["timestamp"] or [],
        **{name: columns[name] for name in COLUMNS[3:]},
    )


def assert_same(fast: Detections | None, expected: Detections) -> None:
    assert fast is not None
    for name in COLUMNS:
        got, want = getattr(fast, name), getattr(expected, name)
        assert got.dtype == want.dtype, name
        assert got.shape == want.shape, name
        if got.dtype.kind == "f":
            assert np.array_equal(got, want, equal_nan=True), name
            assert np.array_equal(np.signbit(got), np.signbit(want)), name
        else:
            assert got.tolist() == want.tolist(), name


@pytest.mark.parametrize(
    "config",
    [
        preset("large"),
        preset("small", miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.05),
        preset("medium", lanes=3, vehicle_lengths=True, vehicle_classes=True),
    ],
)
def test_a_simulated_file_reads_as_the_exact_reader_reads_it(config):
    text = write_detections_csv(simulate(config, seed=4).detections)
    assert_same(fast_detections(text.encode()), exact(text))


def test_unlabelled_and_partly_labelled_targets_are_none_where_empty():
    text = "position,velocity,timestamp,target\n0,20,1,A\n100,20,6,\n"
    assert_same(fast_detections(text.encode()), exact(text))


def test_without_sensor_or_detection_ids_they_are_generated_as_the_exact_reader_does():
    text = "timestamp,velocity,position\n6.0,20,100\n1.0,20,0\n11,20.5,200\n"
    assert_same(fast_detections(text.encode()), exact(text))


@pytest.mark.parametrize(
    "text",
    [
        "\ufeffposition,velocity,timestamp\n0,20,1\n100,20,6\n",  # a byte order mark
        "position,velocity,timestamp\r\n0,20,1\r\n100,20,6\r\n",  # CRLF
        "position,velocity,timestamp\n0,20,1\n100,20,6",  # no newline at the end
        "position,velocity,timestamp\n+0,2e1,.5\n1E2,20.,-6\n",  # every decimal form
        "position,velocity,timestamp,sensor_id\n0,20,1,a\n100,20,6,b\n0,21,3,a\n",
    ],
)
def test_plain_variants_read_as_the_exact_reader_reads_them(text):
    assert_same(fast_detections(text.encode()), exact(text))


@pytest.mark.parametrize(
    "text",
    [
        "position,velocity,timestamp\n0,20,1\n\n100,20,6\n",  # a blank line
        "position,velocity,timestamp\n0,20,1\n100,20\n",  # a short row
        "position,velocity,timestamp\n0,20,1\n100,20,6,7\n",  # a long row
        "position,velocity,timestamp\n0,20, 1\n",  # whitespace
        'position,velocity,timestamp\n0,20,"1"\n',  # quotes
        "position,velocity,timestamp,target\n0,20,1,'=A\n",  # a spreadsheet-safe cell
        "Position,velocity,timestamp\n0,20,1\n",  # a header the exact reader normalises
        "position,velocity,timestamp,speed\n0,20,1,3\n",  # an unknown column
        "position,velocity,timestamp\n0,20,1\r100,20,6\n",  # a bare carriage return
        "position,velocity,timestamp\n0,20,nan\n",
        "position,velocity,timestamp\n0,20,inf\n",
        "position,velocity,timestamp\n0,20,1e13\n",
        "position,velocity,timestamp\n0,-20,1\n",
        "position,velocity,timestamp\n0,20,\n",
        "position,velocity,timestamp\n0,20,1_0\n",
        "position,velocity,timestamp\n0,20,٣\n",
        "position,velocity,timestamp\n0,1e-300,1\n1e12,20,1\n",  # too slow to cross the road
        "position,velocity,timestamp,detection_id\n0,20,1,a\n100,20,6,a\n",
        "position,velocity,timestamp,detection_id\n0,20,1,a\n100,20,6,\n",
        "position,velocity,timestamp,sensor_id\n0,20,1,a\n100,20,6,a\n",
        "position,velocity,timestamp,sensor_id\n0,20,1,a\n100,20,6,\n",
        "position,velocity,timestamp,lane\n0,20,1,1.5\n",
        "position,velocity,timestamp\n",
        "",
    ],
)
def test_anything_but_a_plain_valid_file_is_left_to_the_exact_reader(text):
    assert fast_detections(text.encode()) is None


def test_past_max_rows_is_left_to_the_exact_reader_which_names_the_limit():
    text = "position,velocity,timestamp\n0,20,1\n100,20,6\n"
    assert fast_detections(text.encode(), max_rows=1) is None
    assert fast_detections(text.encode(), max_rows=2) is not None


decimals = st.one_of(
    st.floats(min_value=-1e12, max_value=1e12, allow_nan=False).map(repr),
    st.from_regex(
        r"[+-]?([0-9]{1,20}\.?[0-9]{0,20}|\.[0-9]{1,20})([eE][+-]?[0-9]{1,2})?", fullmatch=True
    ),
)


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(decimals, decimals), min_size=1, max_size=20))
def test_numbers_are_read_to_the_same_float_as_pythons(rows):
    """Polars' float parser against the exact reader's on every decimal form: the same bits,
    or a decline (a value out of range, which the exact reader then names)."""
    body = "".join(f"{p},20,{t}\n" for p, t in rows)
    text = "position,velocity,timestamp\n" + body
    fast = fast_detections(text.encode())
    if fast is not None:
        assert_same(fast, exact(text))


def test_the_width_check_reads_by_chunks_of_whole_lines(monkeypatch):
    from roadlink.association import fast_csv

    monkeypatch.setattr(fast_csv, "_CHUNK_BYTES", 16)
    text = write_detections_csv(simulate(preset("small"), seed=5).detections)
    assert_same(fast_detections(text.encode()), exact(text))
    lines = text.splitlines(keepends=True)
    short = "".join([*lines[:40], "0,20\n", *lines[40:]])
    assert fast_detections(short.encode()) is None
