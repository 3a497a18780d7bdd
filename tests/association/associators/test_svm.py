"""The supervised associators (`associators/svm.py`): they learn from the labelled detections
and label the others."""

import numpy as np
import pytest

from roadlink.association import Detections, associate
from roadlink.association.associators import AssociationError
from roadlink.simulation import preset, simulate


def paper_data(name="large", seed=0, **overrides):
    return simulate(preset(name, **overrides), seed=seed).detections


def test_supervised_associators_refuse_unlabelled_data():
    d = paper_data().without_labels()
    for name in ("svm-linear", "svm-quadratic"):
        with pytest.raises(AssociationError, match="supervised"):
            associate(d, name)


def test_svm_labels_the_unlabelled_from_the_labelled():
    d = paper_data("large", seed=5)
    hidden = np.zeros(len(d), dtype=bool)
    hidden[::3] = True
    partial = Detections.from_columns(
        d.position,
        d.velocity,
        d.timestamp,
        d.sensor_id,
        d.detection_id,
        np.where(hidden, None, d.target).tolist(),
    )
    result = associate(partial, "svm-quadratic")
    # Score the predictions of the hidden third against the truth.
    by_target = {}
    for group, label in zip(result.groups[hidden], d.target[hidden], strict=True):
        by_target.setdefault(label, []).append(group)
    majority = np.mean([max(np.bincount(g)) / len(g) for g in by_target.values()])
    assert majority > 0.8
    assert result.metrics is not None  # scored on the labelled two thirds, out-of-fold


def test_svm_needs_two_labels_and_repeated_labels():
    d = paper_data()
    one_label = Detections.from_columns(d.position, d.velocity, d.timestamp, target=["A"] * len(d))
    with pytest.raises(AssociationError, match="two distinct labels"):
        associate(one_label, "svm-linear")
    unique = Detections.from_columns(
        d.position, d.velocity, d.timestamp, target=[f"x{i}" for i in range(len(d))]
    )
    with pytest.raises(AssociationError, match="at least two detections"):
        associate(unique, "svm-linear")
