"""`roadlink locate` and `roadlink associate --plot` as a user runs them."""

import json

import pytest
from typer.testing import CliRunner

from roadlink.association import associate
from roadlink.association.associators import DEFAULT_ASSOCIATOR
from roadlink.association.csvio import read_detections_csv, write_detections_csv
from roadlink.association.localisation import positions_at, sample_trajectory
from roadlink.cli import app
from roadlink.simulation import preset, simulate
from tests.helpers import with_features

runner = CliRunner()


@pytest.fixture(scope="module")
def large_csv(tmp_path_factory):
    path = tmp_path_factory.mktemp("data") / "large.csv"
    result = runner.invoke(app, ["simulate", "--preset", "large", "--seed", "1", "-o", str(path)])
    assert result.exit_code == 0, result.output
    return path


@pytest.fixture(scope="module")
def library_result(large_csv):
    return associate(read_detections_csv(large_csv.read_text()), DEFAULT_ASSOCIATOR)


def test_positions_at_a_time_as_json_are_the_library_answer(large_csv, library_result):
    result = runner.invoke(app, ["locate", str(large_csv), "--at", "20", "--json"])
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)
    expected = positions_at(library_result, 20.0)
    assert [p["target"] for p in printed] == [p.target for p in expected]
    assert [p["position"] for p in printed] == [p.position for p in expected]


def test_positions_table_has_a_row_per_target_on_the_road(large_csv, library_result):
    result = runner.invoke(app, ["locate", str(large_csv), "--at", "20"])
    assert result.exit_code == 0, result.output
    lines = result.stdout.splitlines()
    assert lines[0].split() == ["target", "position", "velocity"]
    assert len(lines) - 1 == len(positions_at(library_result, 20.0)) > 0


def test_no_target_on_the_road_is_an_empty_answer(large_csv):
    result = runner.invoke(app, ["locate", str(large_csv), "--at", "-100", "--json"])
    assert result.exit_code == 0
    assert json.loads(result.stdout) == []


def test_a_target_trajectory_sampled_by_step(large_csv, library_result):
    result = runner.invoke(app, ["locate", str(large_csv), "--target", "T2", "--step", "5"])
    assert result.exit_code == 0, result.output
    rows = [line.split() for line in result.stdout.splitlines()[1:]]
    expected = sample_trajectory(library_result, "T2", 5.0).samples
    assert [float(r[0]) for r in rows] == pytest.approx([p.time for p in expected], abs=5e-4)
    assert [float(r[1]) for r in rows] == pytest.approx([p.position for p in expected], abs=5e-4)


def test_trajectory_json_has_passes_segments_and_samples(large_csv):
    result = runner.invoke(app, ["locate", str(large_csv), "--target", "t3", "--json"])
    assert result.exit_code == 0, result.output
    printed = json.loads(result.stdout)
    assert printed["target"] == "T3"
    assert len(printed["samples"]) == 101
    assert len(printed["segments"]) == len(printed["passes"]) - 1


def test_segments_of_one_target(large_csv):
    result = runner.invoke(
        app, ["locate", str(large_csv), "--segments", "--target", "T1", "--json"]
    )
    assert result.exit_code == 0, result.output
    segments = json.loads(result.stdout)
    assert segments and {s["target"] for s in segments} == {"T1"}
    for s in segments:
        assert s["mean_speed"] == pytest.approx(s["distance"] / s["travel_time"])


@pytest.mark.parametrize(
    ("args", "message"),
    [
        ([], "choose one of --at, --target and --segments"),
        (["--at", "3", "--segments"], "choose one of"),
        (["--target", "T99"], "unknown target 'T99'; known: T1..T10"),
        (["--at", "3", "--step", "1"], "give --target too"),
        (["--target", "T1", "--step", "0"], "step must be a positive number"),
    ],
)
def test_bad_requests_exit_2_with_the_reason(large_csv, args, message):
    result = runner.invoke(app, ["locate", str(large_csv), *args])
    assert result.exit_code == 2
    assert message in result.stderr


def test_associate_plot_writes_png_and_svg(large_csv, tmp_path):
    png, svg = tmp_path / "out.png", tmp_path / "out.SVG"
    result = runner.invoke(app, ["associate", str(large_csv), "--plot", str(png)])
    assert result.exit_code == 0, result.output
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert "wrote time-space plot" in result.stderr
    result = runner.invoke(
        app,
        ["associate", str(large_csv), "--plot", str(svg), "--plot-kind", "backprojected", "--json"],
    )
    assert result.exit_code == 0, result.output
    assert b"<svg" in svg.read_bytes()
    assert json.loads(result.stdout)["n_targets"] == 10  # the JSON on stdout is unharmed


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["--plot", "out.pdf"], "must end in .png or .svg"),
        (["--plot", "out.png", "--plot-kind", "pie"], "unknown --plot-kind 'pie'"),
    ],
)
def test_associate_plot_rejects_bad_options(large_csv, tmp_path, args, message):
    result = runner.invoke(app, ["associate", str(large_csv), *args])
    assert result.exit_code == 2
    assert message in result.stderr


@pytest.fixture(scope="module")
def featured_csv(tmp_path_factory):
    """The large scenario with lanes from the first three sensors, lengths and classes."""
    detections = simulate(preset("large", false_alarm_rate=0.05), seed=1).detections
    path = tmp_path_factory.mktemp("data") / "featured.csv"
    path.write_text(write_detections_csv(with_features(detections, lane_sensors=3)))
    return path


def test_associate_reads_the_features_and_prints_them_back(featured_csv):
    detections = read_detections_csv(featured_csv.read_text())
    printed = runner.invoke(app, ["associate", str(featured_csv), "--json"])
    assert printed.exit_code == 0, printed.output
    document = json.loads(printed.stdout)
    rows = [r for t in document["targets"] for r in t["detections"]] + document["unassigned"]
    lanes = dict(
        zip(detections.detection_id.tolist(), detections.feature_values("lane"), strict=True)
    )
    assert {r["detection_id"]: r["lane"] for r in rows} == lanes
    assert all(t["vehicle_class"] in ("car", "truck") for t in document["targets"])
    assert document == associate(detections).to_dict()

    matrix = runner.invoke(app, ["associate", str(featured_csv), "--csv"])
    assert matrix.exit_code == 0, matrix.output
    header = matrix.stdout.splitlines()[0].split(",")
    assert header[-3:] == ["S10_lane", "S10_length", "S10_vehicle_class"]


def test_locate_describes_each_target_by_its_length_and_class(featured_csv):
    result = associate(read_detections_csv(featured_csv.read_text()))
    first = result.target_features(result.target_members()[0], result.detections.features)
    at = runner.invoke(app, ["locate", str(featured_csv), "--at", "20", "--json"])
    assert at.exit_code == 0, at.output
    rows = json.loads(at.stdout)
    assert rows and all({"length", "vehicle_class"} <= r.keys() for r in rows)
    table = runner.invoke(app, ["locate", str(featured_csv), "--at", "20"])
    assert table.stdout.split()[:5] == ["target", "position", "velocity", "length", "vehicle_class"]

    one = runner.invoke(app, ["locate", str(featured_csv), "--target", "T1", "--json"])
    assert one.exit_code == 0, one.output
    trajectory = json.loads(one.stdout)
    assert list(trajectory)[:3] == ["target", "length", "vehicle_class"]
    assert {k: trajectory[k] for k in first} == first
    lanes = [p["lane"] for p in trajectory["passes"]]
    assert lanes[3:] == [None] * (len(lanes) - 3) and None not in lanes[:3]


def test_without_features_locate_prints_what_it_always_did(large_csv):
    at = json.loads(runner.invoke(app, ["locate", str(large_csv), "--at", "20", "--json"]).stdout)
    assert {k for r in at for k in r} == {"target", "time", "position", "velocity"}
    one = runner.invoke(app, ["locate", str(large_csv), "--target", "T1", "--json"]).stdout
    trajectory = json.loads(one)
    assert "length" not in trajectory and "lane" not in trajectory["passes"][0]
