"""`roadlink simulate-sumo` (`cli/sumo.py`): its options checked, the install hint without SUMO,
and the CSV it writes (only the end-to-end tests need Eclipse SUMO; they are skipped without it)."""

from __future__ import annotations

import numpy as np
import pytest
from typer.testing import CliRunner

from roadlink.association.csvio import read_detections_csv
from roadlink.cli import app
from roadlink.simulation import sumo
from roadlink.simulation.sumo import sumo_available

needs_sumo = pytest.mark.skipif(
    not sumo_available(), reason="Eclipse SUMO is not installed (pip install 'roadlink[sumo]')"
)


def test_length_noise_needs_features(tmp_path):
    result = CliRunner().invoke(
        app, ["simulate-sumo", "--length-noise", "0.05", "-o", str(tmp_path / "out.csv")]
    )
    assert result.exit_code == 2 and "--length-noise needs --features" in result.output


def test_simulate_sumo_without_sumo_says_how_to_install_it(monkeypatch, tmp_path):
    monkeypatch.setattr(sumo.runner, "sumo_home_candidates", lambda: [tmp_path])
    result = CliRunner().invoke(
        app, ["simulate-sumo", "--scenario", "sumo-dense", "-o", str(tmp_path / "out.csv")]
    )
    assert result.exit_code == 2
    assert "pip install 'roadlink[sumo]'" in result.output
    assert not (tmp_path / "out.csv").exists()


@needs_sumo
def test_sumo_with_features_reports_lanes_and_noisy_lengths_that_follow_the_vehicle(tmp_path):
    out = tmp_path / "features.csv"
    result = CliRunner().invoke(
        app,
        [
            *("simulate-sumo", "--scenario", "sumo-freeflow", "--duration", "60"),
            *("--features", "--length-noise", "0.05", "-o", str(out)),
        ],
    )
    assert result.exit_code == 0, result.output
    d = read_detections_csv(out.read_text())
    assert d.features == ("lane", "length", "vehicle_class")
    assert set(d.lane) <= {0, 1, 2} and len(set(d.lane)) == 3
    assert d.has_length.all() and set(d.vehicle_class) == {"car", "truck"}
    cars, trucks = d.length[d.vehicle_class == "car"], d.length[d.vehicle_class == "truck"]
    assert 3.0 < np.median(cars) < 5.5 < 7.0 < np.median(trucks) < 19.0
    # One vehicle's lengths agree within the 5 % noise; different vehicles' differ.
    labels = d.target.astype(str)
    spread = [np.std(np.log(d.length[labels == v])) for v in np.unique(labels)]
    assert 0.03 < np.median(spread) < 0.07


@needs_sumo
def test_sumo_end_to_end_cli_writes_the_detection_csv(tmp_path):
    out = tmp_path / "bottleneck.csv"
    result = CliRunner().invoke(
        app,
        ["simulate-sumo", "--scenario", "sumo-bottleneck", "--duration", "60", "-o", str(out)],
    )
    assert result.exit_code == 0, result.output
    d = read_detections_csv(out.read_text())
    assert len(d) > 100 and d.labelled.all()


def test_the_help_names_the_extra_that_installs_sumo_and_the_roads_it_simulates():
    # Rich reads "[sumo]" as markup unless escaped: the help once said "pip install 'roadlink'".
    result = CliRunner().invoke(app, ["simulate-sumo", "--help"], terminal_width=120)
    assert result.exit_code == 0
    assert "pip install 'roadlink[sumo]'" in result.output
    assert "traffic lights" in result.output and "sumo-arterial" in result.output
