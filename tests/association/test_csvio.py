import pytest

from roadlink.association import DetectionError, associate
from roadlink.association.csvio import (
    read_detections_csv,
    spreadsheet_safe,
    spreadsheet_safe_column,
    spreadsheet_safe_texts,
    write_detections_csv,
)
from roadlink.association.detections import Detections
from roadlink.association.text_columns import text_column
from roadlink.simulation import preset, simulate


def test_round_trip_keeps_every_column():
    d = simulate(preset("small", false_alarm_rate=0.1), seed=3).detections
    back = read_detections_csv(write_detections_csv(d))
    assert back.detection_id.tolist() == d.detection_id.tolist()
    assert back.target.tolist() == d.target.tolist()
    assert back.sensor_id.tolist() == d.sensor_id.tolist()
    assert back.timestamp.tolist() == d.timestamp.tolist()  # repr round-trips floats exactly


def test_minimal_csv_with_header_in_any_case_and_order():
    text = "Timestamp,VELOCITY,position\n1.0,20,0\n6.0,20,100\n"
    d = read_detections_csv(text)
    assert d.position.tolist() == [0.0, 100.0]
    assert d.target.tolist() == [None, None]


def test_empty_target_cells_mean_unlabelled():
    text = "position,velocity,timestamp,target\n0,20,1,A\n100,20,6,\n"
    assert read_detections_csv(text).target.tolist() == ["A", None]


@pytest.mark.parametrize(
    ("text", "where"),
    [
        ("", "empty"),
        ("position,velocity\n0,1\n", "timestamp"),
        ("position,velocity,timestamp\n", "no detections"),
        ("position,velocity,timestamp\n0,20,1\n100,20\n", "row 2"),
        ("position,velocity,timestamp\n0,20,1\n100,fast,6\n", "row 2, field 'velocity'"),
        ("position,velocity,timestamp\n0,20,1\n100,20,\n", "row 2, field 'timestamp'"),
        ("position,velocity,timestamp\n0,-20,1\n100,20,3\n", "row 1, field 'velocity'"),
        ("position,position,velocity,timestamp\n0,0,20,1\n", "more than once"),
        ('position,velocity,timestamp\n0,20,"1\n', "row 1"),
    ],
)
def test_bad_csv_says_what_and_where(text, where):
    with pytest.raises(DetectionError) as excinfo:
        read_detections_csv(text)
    assert where in str(excinfo.value)


def test_matrix_csv_is_one_row_per_target_one_column_group_per_sensor():
    d = simulate(preset("large"), seed=1).detections
    lines = associate(d, "svm-quadratic").to_matrix_csv().splitlines()
    header = lines[0].split(",")
    assert header[0] == "target"
    assert header[1:4] == ["S1_detection_id", "S1_velocity", "S1_timestamp"]
    assert len(header) == 1 + 3 * 10
    assert len(lines) == 1 + 10
    ids = [cell for line in lines[1:] for cell in line.split(",")[1::3] for cell in cell.split(";")]
    assert sorted(i for i in ids if i) == sorted(d.detection_id.tolist())


def test_text_cells_that_a_spreadsheet_would_run_are_escaped_and_read_back_as_they_were():
    ids = ["=1+2", "+S2", "-x", "@d", "'=already quoted", "'plain", "plain", "-"]
    d = Detections.from_columns(
        [0.0] * len(ids),
        [-1.5 + 31.5] * len(ids),
        [float(k) for k in range(len(ids))],
        sensor_id=["=S1"] * len(ids),
        detection_id=ids,
        target=["@T"] * len(ids),
    )
    text = write_detections_csv(d)
    assert "'=1+2" in text and "'=S1" in text and "'@T" in text and ",plain," in text
    back = read_detections_csv(text)
    assert back.detection_id.tolist() == ids
    assert set(back.sensor_id.tolist()) == {"=S1"} and set(back.target.tolist()) == {"@T"}


def test_an_unknown_column_is_refused_by_name_as_json_refuses_an_unknown_field():
    text = "position,velocity,timestamp,velocty\n0,30,1,31\n"
    with pytest.raises(DetectionError, match="field 'velocty': unknown column; the known columns"):
        read_detections_csv(text)


def test_features_round_trip_with_empty_cells_where_a_detection_reports_none():
    text = (
        "position,velocity,timestamp,lane,length,vehicle_class\n"
        "0,20,1,0,4.5,car\n"
        "100,20,6,,,\n"
        "0,25,2,2,,=truck\n"
    )
    d = read_detections_csv(text)
    assert d.lane.tolist() == [0, -1, 2]
    assert d.length[0] == 4.5 and d.has_length.tolist() == [True, False, False]
    assert d.vehicle_class.tolist() == ["car", None, "=truck"]
    written = write_detections_csv(d)
    assert written.splitlines()[0].endswith(",target,lane,length,vehicle_class")
    assert "'=truck" in written  # a class is a text cell, escaped for spreadsheets
    back = read_detections_csv(written)
    assert back.lane.tolist() == d.lane.tolist()
    assert back.vehicle_class.tolist() == d.vehicle_class.tolist()
    assert back.length[0] == 4.5 and back.has_length.tolist() == d.has_length.tolist()


def test_without_features_the_csv_has_no_feature_columns():
    d = simulate(preset("small"), seed=1).detections
    assert write_detections_csv(d).splitlines()[0] == (
        "position,velocity,timestamp,sensor_id,detection_id,target"
    )


def test_a_bad_feature_cell_names_row_and_field():
    text = "position,velocity,timestamp,lane,length\n0,20,1,1,4\n100,20,6,1.5,0\n"
    with pytest.raises(DetectionError) as excinfo:
        read_detections_csv(text)
    assert [(p.row, p.field) for p in excinfo.value.problems] == [(2, "lane"), (2, "length")]


def test_a_header_that_is_not_valid_csv_is_a_problem_not_a_crash():
    with pytest.raises(DetectionError, match="the header is not valid CSV"):
        read_detections_csv('"\u00ef')


def test_spreadsheet_safe_texts_is_spreadsheet_safe_of_each():
    plain = ["d1", "a=b", "x-1"]
    assert spreadsheet_safe_texts(plain) == plain
    mixed = ["d1", "=1+1", "-2", "'x", "\tt", "@a", "+"]
    assert spreadsheet_safe_texts(mixed) == [spreadsheet_safe(t) for t in mixed]


def test_spreadsheet_safe_column_is_spreadsheet_safe_of_each():
    texts = ["d1", "=1+1", "-2", "'x", "\tt", "\rr", "@a", "+", "", "a=b", "x'", " =", "\u00e9="]
    assert spreadsheet_safe_column(text_column(texts)).to_list() == list(
        map(spreadsheet_safe, texts)
    )


@pytest.mark.parametrize(("rows", "loads_polars"), [(10, False), (30_000, True)])
def test_a_small_file_is_read_without_loading_polars(tmp_path, rows, loads_polars):
    """In a process that has not loaded polars, a file of up to SMALL_BYTES is read by the exact
    reader (loading polars costs more than that read); a larger one by the fast path. Either
    reads the same detections (tests/association/test_fast_csv.py)."""
    import subprocess
    import sys

    from roadlink.association.csvio import SMALL_BYTES

    path = tmp_path / "d.csv"
    path.write_text(
        "position,velocity,timestamp\n"
        + "".join(f"{k % 5 * 100},20,{k % 5 * 5 + k}\n" for k in range(rows))
    )
    assert (path.stat().st_size > SMALL_BYTES) == loads_polars
    script = (
        "import sys; from pathlib import Path\n"
        "from roadlink.association.csvio import read_detections_csv\n"
        f"d = read_detections_csv(Path({str(path)!r}))\n"
        f"text = read_detections_csv(Path({str(path)!r}).read_bytes())\n"
        "print(len(d), len(text), 'polars' in sys.modules)\n"
    )
    out = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True)
    assert out.returncode == 0, out.stderr
    assert out.stdout.split() == [str(rows), str(rows), str(loads_polars)]
