"""benchmarks/link_confidence.py: its tables, and its links on a committed SUMO case."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from benchmarks.link_confidence import links, tables
from roadlink.association.csvio import read_detections_csv

SUMO = Path(__file__).parents[1] / "data" / "sumo"


def test_the_trade_off_counts_correct_against_true_links_and_false_against_kept_ones() -> None:
    confidence = np.array([0.95, 0.8, 0.6, 0.3])
    right = np.array([True, True, False, False])
    summary = tables(confidence, right, true_links=4)
    by_threshold = {row["min_confidence"]: row for row in summary["trade_off"]}
    assert by_threshold[0.0] == {"min_confidence": 0.0, "correct": 0.5, "false": 0.5}
    assert by_threshold[0.7] == {"min_confidence": 0.7, "correct": 0.5, "false": 0.0}
    assert by_threshold[0.99]["false"] is None  # nothing kept
    first_bin = summary["calibration"][0]
    assert first_bin == {"bin": [0.0, 0.5], "links": 1, "right": 0.0}
    assert summary["mean_confidence"] == pytest.approx(0.6625)


def test_links_of_a_sumo_case_are_judged_against_the_vehicles() -> None:
    d = read_detections_csv((SUMO / "sumo-freeflow.csv").read_text())
    confidence, right, true_links = links(d)
    labels = d.target.astype(str)
    assert true_links == len(labels) - np.unique(labels).size
    assert confidence.size == right.size <= true_links
    # Free flow: nearly every link right, and the sure ones all right.
    assert right.mean() > 0.97 and right[confidence > 0.99].all()
