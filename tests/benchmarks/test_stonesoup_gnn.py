"""The Stone Soup adapter: a GNN tracker in (passing time, pace) with road position as its clock."""

import numpy as np
import pytest

pytest.importorskip("stonesoup", reason="Stone Soup (the bench extra) is absent")

from benchmarks.stonesoup_gnn import sensor_scans, track_groups
from roadlink.association.scores import score_grouping
from roadlink.simulation import preset, simulate


def test_constant_speed_targets_are_tracked_perfectly():
    config = preset("large", n_targets=5, velocity_model="constant")
    detections = simulate(config, seed=3).detections
    groups = track_groups(detections.without_labels())
    metrics = score_grouping(groups, detections.target)
    assert metrics is not None
    assert metrics.accuracy == 1.0 and metrics.complete_targets == 1.0
    assert np.unique(groups).size == 5


def test_each_sensor_is_one_scan_in_road_order():
    detections = simulate(preset("small", n_targets=4), seed=0).detections
    from stonesoup.models.measurement.linear import LinearGaussian

    model = LinearGaussian(ndim_state=2, mapping=(0, 1), noise_covar=np.eye(2))
    scans = list(sensor_scans(detections, model))
    assert len(scans) == detections.sensor_positions.size
    times = [when for when, _ in scans]
    assert times == sorted(times)
    rows = sorted(d.metadata["row"] for _, scan in scans for d in scan)
    assert rows == list(range(len(detections)))
    _, first = scans[0]
    for d in first:
        row = d.metadata["row"]
        assert d.state_vector[0, 0] == detections.timestamp[row]
        assert d.state_vector[1, 0] == pytest.approx(1.0 / detections.velocity[row])
