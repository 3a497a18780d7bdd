"""`roadlink simulate` and `roadlink associate` (`cli/analysis.py`) as a user runs them."""

import dataclasses
import json
import subprocess
import sys
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from roadlink.association import associate
from roadlink.association.associators import ASSOCIATORS
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.cli import app
from roadlink.simulation import preset, simulate
from tests.helpers import COMMITTED_DENSE

runner = CliRunner()


@pytest.fixture(scope="module")
def small_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "small.csv"
    result = runner.invoke(app, ["simulate", "--preset", "small", "--seed", "3", "-o", str(path)])
    assert result.exit_code == 0, result.output
    return path


def test_simulate_writes_the_detection_csv(small_csv):
    d = read_detections_csv(small_csv.read_text())
    assert len(d) == 100
    assert small_csv.read_text().splitlines()[0] == (
        "position,velocity,timestamp,sensor_id,detection_id,target"
    )


def test_simulate_reports_lanes_lengths_and_classes_when_asked(tmp_path):
    path = tmp_path / "features.csv"
    flags = ["--lanes", "3", "--lane-change", "0.2", "--lengths", "--length-noise", "0.05"]
    result = runner.invoke(
        app, ["simulate", "--preset", "small", "--seed", "3", *flags, "--classes", "-o", str(path)]
    )
    assert result.exit_code == 0, result.output
    text = path.read_text()
    assert text.splitlines()[0].endswith(",target,lane,length,vehicle_class")
    expected = simulate(
        preset(
            "small",
            lanes=3,
            lane_change_probability=0.2,
            vehicle_lengths=True,
            length_noise=0.05,
            vehicle_classes=True,
        ),
        seed=3,
    ).detections
    assert text == write_detections_csv(expected)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--lane-change", "0.3"], "lane_change_probability: needs lanes"),
        (["--length-noise", "0.05"], "length_noise: needs vehicle_lengths"),
        (["--lanes", "0"], "lanes: Input should be greater than or equal to 1"),
    ],
)
def test_simulate_refuses_feature_flags_that_make_no_sense(tmp_path, flags, message):
    result = runner.invoke(app, ["simulate", *flags, "-o", str(tmp_path / "x.csv")])
    assert result.exit_code == 2
    # One line naming the setting, not pydantic's report of every input value.
    assert result.stderr.startswith(f"error: {message}") and result.stderr.count("\n") == 1
    assert not (tmp_path / "x.csv").exists()


def test_simulate_help_names_the_feature_flags():
    result = runner.invoke(app, ["simulate", "--help"], terminal_width=200)
    for flag in ("--lanes", "--lane-change", "--lengths", "--no-lengths", "--length-noise"):
        assert flag in result.stdout
    assert "--classes" in result.stdout


@pytest.mark.parametrize("name", sorted(ASSOCIATORS))
def test_associate_json_is_the_library_result(small_csv, name):
    result = runner.invoke(app, ["associate", str(small_csv), "--associator", name, "--json"])
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)
    expected = associate(read_detections_csv(small_csv.read_text()), name).to_dict()
    assert printed == json.loads(json.dumps(expected))


def test_associate_csv_prints_the_target_matrix(small_csv):
    result = runner.invoke(
        app, ["associate", str(small_csv), "--associator", "svm-quadratic", "--csv"]
    )
    assert result.exit_code == 0
    lines = result.stdout.splitlines()
    assert lines[0].startswith("target,S1_detection_id,S1_velocity,S1_timestamp,S2_")
    assert len(lines) == 11


def test_params_are_typed_and_checked(small_csv):
    ok = runner.invoke(
        app,
        ["associate", str(small_csv), "--associator", "kmeans", "--param", "n_targets=4", "--json"],
    )
    assert ok.exit_code == 0
    assert json.loads(ok.stdout)["n_targets"] == 4
    bad = runner.invoke(
        app, ["associate", str(small_csv), "--associator", "kmeans", "--param", "n_targets=many"]
    )
    assert bad.exit_code == 2
    assert "n_targets" in bad.stderr
    malformed = runner.invoke(app, ["associate", str(small_csv), "--param", "oops"])
    assert malformed.exit_code == 2 and "key=value" in malformed.stderr


def test_bad_input_is_a_clear_error(tmp_path):
    path = tmp_path / "bad.csv"
    path.write_text("position,velocity,timestamp\n0,20,1\n100,-3,6\n")
    result = runner.invoke(app, ["associate", str(path)])
    assert result.exit_code == 2
    assert "row 2, field 'velocity': must be > 0" in result.stderr
    missing = runner.invoke(app, ["associate", str(tmp_path / "absent.csv")])
    assert missing.exit_code == 2 and "cannot read" in missing.stderr
    directory = runner.invoke(app, ["associate", str(tmp_path)])
    assert directory.exit_code == 2 and "cannot read" in directory.stderr
    latin = tmp_path / "latin.csv"
    latin.write_bytes(b"position,velocity,timestamp,target\n0,20,1,caf\xe9\n")
    result = runner.invoke(app, ["associate", str(latin)])
    assert result.exit_code == 2
    assert "latin.csv: not UTF-8 text: byte 46 (invalid continuation byte)" in result.stderr


@pytest.mark.parametrize("bom", [b"", b"\xef\xbb\xbf"])
@pytest.mark.parametrize("line_end", [b"\n", b"\r\n"])
def test_a_file_reads_as_its_bytes_do(tmp_path, bom, line_end):
    """A file is mapped and read by polars itself; with a byte-order mark or CRLF line ends,
    as its bytes: the same detections either way."""
    d = simulate(preset("small"), seed=1).detections
    data = (
        bom
        + write_detections_csv(d).replace("\n", "\r\n" if line_end == b"\r\n" else "\n").encode()
    )
    path = tmp_path / "d.csv"
    path.write_bytes(data)
    from_file, from_bytes = read_detections_csv(path), read_detections_csv(data)
    for name in ("position", "velocity", "timestamp", "sensor_id", "detection_id", "target"):
        assert getattr(from_file, name).tolist() == getattr(from_bytes, name).tolist()
    assert from_file.detection_id.tolist() == d.detection_id.tolist()


def test_unlabelled_simulation_has_no_metrics(tmp_path):
    path = tmp_path / "u.csv"
    runner.invoke(app, ["simulate", "--unlabelled", "-o", str(path)])
    result = runner.invoke(app, ["associate", str(path), "--associator", "kmeans++", "--json"])
    assert json.loads(result.stdout)["metrics"] is None


def test_the_command_ends_with_the_collector_frozen(monkeypatch):
    """`roadlink` (`main`) runs the app and, however it ends, freezes the garbage collector, so
    that the interpreter's exit does not collect every object of numpy, polars and scipy."""
    import gc

    import roadlink.cli

    frozen = []
    monkeypatch.setattr(gc, "freeze", lambda: frozen.append(True))

    def app() -> None:
        raise SystemExit(3)

    monkeypatch.setattr(roadlink.cli, "app_for", lambda args: app)
    with pytest.raises(SystemExit) as ended:
        roadlink.cli.main()
    assert ended.value.code == 3 and frozen == [True]


def test_the_json_rows_are_made_while_the_file_is_associated(small_csv, monkeypatch):
    """`--json` makes the rows' text that needs no grouping on a thread beside the association
    (polars' rows: from any size here), and prints the same bytes as the plain encoder."""
    from roadlink.association import result_text
    from roadlink.cli import analysis

    made_on = []
    making = analysis.json_detection_texts

    def recorded(detections):
        made_on.append(threading.current_thread().name)
        return making(detections)

    monkeypatch.setattr(result_text, "_POLARS_ROWS", 0)
    monkeypatch.setattr(analysis, "json_detection_texts", recorded)
    result = runner.invoke(app, ["associate", str(small_csv), "--json"])
    assert result.exit_code == 0, result.output
    expected = associate(read_detections_csv(small_csv), "assignment").to_dict()
    assert result.stdout == json.dumps(expected, indent=2) + "\n"
    assert len(made_on) == 1 and made_on[0].startswith("roadlink-meanwhile")


def test_the_json_is_scored_while_its_rows_are_written(small_csv, monkeypatch):
    """`--json` scores the result on a thread while the rows are written (the metrics come
    last), from the true labels read while the detections were associated; the other
    outputs are scored at once."""
    from roadlink.association.result import AssociationResult
    from roadlink.cli import analysis

    scored_on, truths_read_on = [], []
    scoring, reading = AssociationResult.scored, analysis.truth_of_detections

    def recorded(self, truth=None):
        scored_on.append((threading.current_thread().name, truth is not None))
        return scoring(self, truth)

    def read(detections):
        truths_read_on.append(threading.current_thread().name)
        return reading(detections)

    monkeypatch.setattr(AssociationResult, "scored", recorded)
    monkeypatch.setattr(analysis, "truth_of_detections", read)
    result = runner.invoke(app, ["associate", str(small_csv), "--json"])
    assert result.exit_code == 0, result.output
    expected = associate(read_detections_csv(small_csv), "assignment").to_dict()
    assert json.loads(result.stdout)["metrics"] == expected["metrics"] is not None
    assert len(scored_on) == 1 and scored_on[0][0].startswith("roadlink-scoring")
    assert scored_on[0][1] and truths_read_on[0].startswith("roadlink-meanwhile")
    summary = runner.invoke(app, ["associate", str(small_csv)])
    assert "accuracy=" in summary.stdout and len(scored_on) == 1
    assert analysis.associate_file(small_csv, "assignment", []).metrics is not None


def test_work_beside_the_association_sees_the_detections_and_its_errors_surface(small_csv):
    from roadlink.cli import analysis

    seen = []
    result = analysis.associate_file(small_csv, "assignment", [], seen.append)
    assert seen == [result.detections]

    def broken(detections):
        raise RuntimeError("beside")

    with pytest.raises(RuntimeError, match="beside"):
        analysis.associate_file(small_csv, "assignment", [], broken)


def associate_with_middle_sensor_off(
    tmp_path: Path, column: str, change: Callable[[np.ndarray], np.ndarray]
) -> tuple[float, subprocess.CompletedProcess[str]]:
    """`roadlink associate` on the committed dense case with the middle sensor's `column`
    changed, in a process of its own, as a user runs it: the sensor's position and the run."""
    dense = read_detections_csv(COMMITTED_DENSE)
    middle = np.unique(dense.position)[5]
    at_middle = dense.position == middle
    values = getattr(dense, column).copy()
    values[at_middle] = change(values[at_middle])
    path = tmp_path / "off.csv"
    path.write_text(write_detections_csv(dataclasses.replace(dense, **{column: values})))
    out = subprocess.run(
        [sys.executable, "-m", "roadlink.cli", "associate", str(path)],
        capture_output=True,
        text=True,
    )
    assert out.returncode == 0, out.stderr
    assert "accuracy" in out.stdout
    return float(middle), out


def test_associate_names_a_sensor_reporting_km_per_hour_on_stderr(tmp_path):
    """Among sensors in m/s, one sends km/h; the command says which (`assignment/weak_bias.py`)."""
    middle, out = associate_with_middle_sensor_off(tmp_path, "velocity", lambda v: v * 3.6)
    assert f"the sensor at position {middle:g} reads speeds about 3." in out.stderr
    assert "its speed calibration or unit is off" in out.stderr


def test_associate_names_a_sensor_whose_clock_is_off_on_stderr(tmp_path):
    """The association sets the clock right (`assignment/clocks.py`); the command says which
    sensor it was."""
    middle, out = associate_with_middle_sensor_off(tmp_path, "timestamp", lambda t: t + 20.0)
    assert f"the sensor at position {middle:g} stamps its detections" in out.stderr
    assert "s later than the sensors either side of it" in out.stderr
