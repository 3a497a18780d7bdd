import numpy as np
from hypothesis import given
from hypothesis import strategies as st

from roadlink.association.backprojection import (
    backproject_times,
    backprojected_features,
    recover_times,
)
from roadlink.association.detections import Detections
from roadlink.simulation import preset, simulate


def test_the_papers_worked_example():
    # V = 20 m/s, T = 50 s, R2 - R1 = 100: T' = 45 s.
    out = backproject_times(np.array([100.0]), np.array([20.0]), np.array([50.0]), 0.0)
    assert out.tolist() == [45.0]


def test_reference_is_the_sensor_with_the_smallest_position():
    d = Detections.from_columns([300.0, 200.0], [10.0, 10.0], [40.0, 30.0])
    features = backprojected_features(d)
    # Reference at 200: the detection at 300 moves back by 100 / 10 = 10 s.
    np.testing.assert_allclose(features[:, 1], [30.0, 30.0])
    np.testing.assert_allclose(features[:, 0], [10.0, 10.0])
    np.testing.assert_allclose(backprojected_features(d, backproject=False)[:, 1], [40.0, 30.0])


def test_constant_speed_target_maps_to_one_point():
    positions = np.array([0.0, 150.0, 400.0, 1000.0])
    d = Detections.from_columns(positions, np.full(4, 25.0), 7.0 + positions / 25.0)
    np.testing.assert_allclose(backprojected_features(d)[:, 1], 7.0)


@given(
    st.floats(0, 1e4),
    st.floats(0.1, 100),
    st.floats(-1e5, 1e5),
    st.floats(-1e3, 1e3),
)
def test_recovery_inverts_backprojection(position, velocity, timestamp, reference):
    args = (np.array([position]), np.array([velocity]))
    back = backproject_times(*args, np.array([timestamp]), reference)
    np.testing.assert_allclose(recover_times(*args, back, reference), [timestamp], atol=1e-6)


def test_raw_features_are_the_unprocessed_timestamps():
    d = simulate(preset("large"), seed=0).detections
    np.testing.assert_array_equal(backprojected_features(d, False)[:, 1], d.timestamp)
