"""The fast CSV path reads a plain, valid file exactly as the exact reader does, and declines
(None) everything else, which the exact reader then reads (and names the problems of)."""

from dataclasses import replace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadlink.association.csvio import read_csv_columns, write_detections_csv
from roadlink.association.detections import COLUMNS, Detections
from roadlink.association.fast_csv import fast_detections
from roadlink.association.feature_columns import classes_in_order
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
        # Features, some not reported (empty cells), a lane written as a float.
        "position,velocity,timestamp,lane,length,vehicle_class\n"
        "0,20,1,0,4.5,car\n100,20,6,,,\n200,20,11,2.0,12,truck\n300,20,16,255,100,bus\n",
        # Features no row reports, and lanes and lengths every row does.
        "position,velocity,timestamp,lane,length,vehicle_class\n0,20,1,,,\n100,20,6,,,\n",
        "position,velocity,timestamp,lane,length\n0,20,1,-0,0.1\n100,20,6,3,99.9\n",
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
        "position,velocity,timestamp,sensor_id\n0,20,1,a\u00a0\n100,20,6,b\n",  # Python strips it
        "position,velocity,timestamp,sensor_id\n0,20,1,\u00e9\n100,20,6,b\n",  # beyond ASCII
        "position,velocity,timestamp\n0,1e-300,1\n1e12,20,1\n",  # too slow to cross the road
        "position,velocity,timestamp,detection_id\n0,20,1,a\n100,20,6,a\n",
        "position,velocity,timestamp,detection_id\n0,20,1,a\n100,20,6,\n",
        "position,velocity,timestamp,sensor_id\n0,20,1,a\n100,20,6,a\n",
        "position,velocity,timestamp,sensor_id\n0,20,1,a\n100,20,6,\n",
        "position,velocity,timestamp,lane\n0,20,1,1.5\n",
        "position,velocity,timestamp,lane\n0,20,1,nan\n",
        "position,velocity,timestamp,lane\n0,20,1,inf\n",
        "position,velocity,timestamp,lane\n0,20,1,-1\n",
        "position,velocity,timestamp,lane\n0,20,1,256\n",
        "position,velocity,timestamp,length\n0,20,1,0\n",
        "position,velocity,timestamp,length\n0,20,1,-4\n",
        "position,velocity,timestamp,length\n0,20,1,nan\n",
        "position,velocity,timestamp,length\n0,20,1,inf\n",
        "position,velocity,timestamp,length\n0,20,1,100.5\n",
        "position,velocity,timestamp,vehicle_class\n0,20,1," + "x" * 33 + "\n",
        # A "nan" beside empty cells (read as NaN too), an infinity or a half lane among them.
        "position,velocity,timestamp,length\n0,20,1,\n100,20,6,nan\n200,20,11,4\n",
        "position,velocity,timestamp,lane\n0,20,1,\n100,20,6,nan\n200,20,11,1\n",
        "position,velocity,timestamp,lane\n0,20,1,\n100,20,6,-inf\n",
        "position,velocity,timestamp,lane\n0,20,1,\n100,20,6,0.5\n",
        "position,velocity,timestamp,length\n0,20,1,\n100,20,6,inf\n",
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


def test_the_exact_byte_count_reads_by_chunks(monkeypatch):
    """A file with marks the one comparison counts (`!#$%&`) is counted again exactly, by
    chunks, as a file past polars' 32-bit counts is: still read, and a short line still
    declined."""
    from roadlink.association import fast_csv

    monkeypatch.setattr(fast_csv, "_CHUNK_BYTES", 16)
    monkeypatch.setattr(fast_csv, "_POLARS_MAX_BYTES", 1000)  # this file's counts too
    detections = simulate(preset("small"), seed=5).detections
    marked = detections.sensor_id.astype(str).astype(object) + "#!"
    text = write_detections_csv(replace(detections, sensor_id=marked))
    assert_same(fast_detections(text.encode()), exact(text))
    lines = text.splitlines(keepends=True)
    short = "".join([*lines[:40], "0,20\n", *lines[40:]])
    assert fast_detections(short.encode()) is None


@pytest.mark.parametrize("end", ["\n", "\r\n"])
@pytest.mark.parametrize("cell", ["a#1", "b!", "$c", "d%&e", "'=A", 'x"y', "a b", "a\x1f"])
def test_marks_up_to_the_quote_read_alike_and_quotes_and_blanks_are_declined(end, cell):
    """The bytes up to `'` are counted as one: `!#$%&` (read alike by both readers) are told
    apart from quotes and blanks (declined) after, with LF and CRLF line ends."""
    rows = ["position,velocity,timestamp,sensor_id", f"0,20,1,{cell}", "100,20,6,b", ""]
    text = end.join(rows)
    fast = fast_detections(text.encode())
    if any(c in cell for c in "'\" \x1f"):
        assert fast is None
    else:
        assert_same(fast, exact(text))


def test_text_codes_without_polars_categories_as_with(monkeypatch):
    """Older polars (no `Categories`): the codes come from an Enum of the distinct values."""
    import polars as pl

    text = write_detections_csv(
        simulate(preset("medium", lanes=3, vehicle_classes=True), seed=3).detections
    )
    with_categories = fast_detections(text.encode())
    monkeypatch.delattr(pl, "Categories")
    assert_same(fast_detections(text.encode()), exact(text))
    assert_same(with_categories, exact(text))


@pytest.mark.parametrize("where", [1, 5_000, 19_999])
@pytest.mark.parametrize("line", ["0,20,1,S1,x", "0,20,1,S1,x,A,B", "", "0,20,1,S1,x,A,"])
def test_a_line_of_another_width_anywhere_in_a_large_file_is_declined(where, line):
    """polars parses a large file in chunks on several threads: a narrower or wider line, or
    a blank one, is caught wherever it falls (the comma count, and polars' refusal of a line
    wider than the header)."""
    rows = [f"{100 * (i % 50)},20,{i},S{i % 50},d{i},A{i // 50}" for i in range(20_000)]
    header = "position,velocity,timestamp,sensor_id,detection_id,target"
    assert fast_detections("\n".join([header, *rows, ""]).encode()) is not None
    rows.insert(where, line)
    assert fast_detections("\n".join([header, *rows, ""]).encode()) is None


@pytest.mark.parametrize("byte", ["\x1c", "\x1d", "\x1e", "\x1f", "\x00", "\x07", "\x7f"])
def test_a_control_character_is_left_to_the_exact_reader(byte):
    """Python's `str.strip` drops \\x1c-\\x1f as whitespace, polars keeps them: declined."""
    text = f"position,velocity,timestamp,sensor_id\n0,20,1,a{byte}\n100,20,6,b\n"
    fast = fast_detections(text.encode())
    if byte == "\x7f":  # not whitespace to either reader: read alike
        assert_same(fast, exact(text))
    else:
        assert fast is None


def test_text_columns_share_one_object_per_distinct_value():
    text = write_detections_csv(simulate(preset("medium"), seed=2).detections)
    fast = fast_detections(text.encode())
    assert_same(fast, exact(text))
    assert fast is not None
    for name in ("sensor_id", "target"):
        values = getattr(fast, name).tolist()
        assert len({id(v) for v in values}) == len(set(values))


def test_classes_come_coded_as_a_block_codes_them():
    """The fast path hands on the classes' codes (`Detections.class_codes`), in the order a
    block numbers them: the same as coding the classes it read, row by row."""
    text = (
        "position,velocity,timestamp,vehicle_class\n"
        "0,20,1,\n100,20,6,van\n0,21,2,car\n100,21,7,van\n0,22,3,\n100,22,8,car\n"
    )
    fast = fast_detections(text.encode())
    assert fast is not None
    assert fast.class_codes() is fast.class_codes()  # the parser's, not coded again
    expected = classes_in_order(fast.vehicle_class.tolist())
    assert fast.class_codes().words == expected.words == [None, "van", "car"]
    assert fast.class_codes().codes.tolist() == expected.codes.tolist() == [0, 1, 2, 1, 0, 2]


cells = st.text(alphabet=st.characters(min_codepoint=0, max_codepoint=0x2FF), max_size=6)


@settings(max_examples=300, deadline=None)
@given(st.lists(st.tuples(cells, cells, cells), min_size=1, max_size=8))
def test_any_text_cells_read_as_the_exact_reader_reads_them_or_are_declined(rows):
    """Sensor ids, detection ids and targets of any characters (quotes, commas, whitespace,
    controls, non-ASCII): the fast path reads what the exact reader reads, or declines. The
    file is written as csv.writer would, so that quoting is exercised too."""
    import csv
    import io

    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(["position", "velocity", "timestamp", "sensor_id", "detection_id", "target"])
    for k, (sensor, detection, target) in enumerate(rows):
        writer.writerow([0, 20, k, sensor, detection, target])
    text = out.getvalue()
    try:
        expected = exact(text)
    except (ValueError, csv.Error):
        expected = None  # the exact reader refuses it: the fast path must decline too
    fast = fast_detections(text.encode())
    if expected is None:
        assert fast is None
    elif fast is not None:
        assert_same(fast, expected)
