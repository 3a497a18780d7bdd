"""The paper's comparison study (`simulation/study.py`): its variants, and one run of them."""

import numpy as np
import pytest

from roadlink.association import associate
from roadlink.association.associators import ASSOCIATORS
from roadlink.simulation import preset, simulate
from roadlink.simulation.study import StudyRow, Variant, run_study, study_variants


def test_every_associator_with_a_backproject_switch_also_runs_on_raw_data():
    variants = study_variants()
    assert {v.associator for v in variants} == set(ASSOCIATORS)
    for name, cls in ASSOCIATORS.items():
        mine = [v for v in variants if v.associator == name]
        if "backproject" in cls.Params.model_fields:
            assert mine == [Variant(name, True), Variant(name, False)]
        else:
            assert mine == [Variant(name, None)]
    assert study_variants(["kmeans"]) == [Variant("kmeans", True), Variant("kmeans", False)]


def test_a_variant_names_itself_and_its_parameters():
    assert (Variant("kmeans", True).label, Variant("kmeans", True).params) == (
        "kmeans",
        {"backproject": True},
    )
    assert Variant("kmeans", False).label == "kmeans (raw)"
    assert (Variant("assignment", None).label, Variant("assignment", None).params) == (
        "assignment",
        {},
    )


def test_a_run_scores_every_variant_on_the_same_seeds():
    steps = []
    variants = [Variant("kmeans++", True), Variant("kmeans++", False)]
    rows = run_study(["small"], variants, seeds=2, on_step=lambda: steps.append(1))
    assert len(steps) == 4 and [r.variant for r in rows] == variants
    for row in rows:
        expected = [
            associate(simulate(preset("small"), seed=s).detections, "kmeans++", row.variant.params)
            for s in range(2)
        ]
        assert row.accuracies == tuple(r.metrics.accuracy for r in expected)  # type: ignore[union-attr]


def test_a_row_summarises_its_accuracies():
    row = StudyRow("small", Variant("kmeans", True), (0.5, 0.7, 0.9))
    assert row.mean == pytest.approx(0.7)
    assert row.std == pytest.approx(np.std([0.5, 0.7, 0.9]))
    assert row.minimum == 0.5
