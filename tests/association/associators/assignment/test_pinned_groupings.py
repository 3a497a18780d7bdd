"""`assignment`'s groupings of the committed cases, pinned: work on its speed must leave every
one of them as it was, to the last detection.

The digests were computed by the code before the speed work of 2026-11-26 (commit dff7505); the
fast paths since (the gate's cost bounds, the re-pairing sweep's gating among the suffixes' heads,
the matchings, the medians) return exactly what the plain code did. The lane anchors' chains of
the same day (learned smoothness, margins) moved the three featured cases whose anchors weigh
in, and `feature_weight=0` now turns the anchors off (its grouping is the featureless one).
The track's pace read from its travel times (`assignment/pace.py`, later that day) moved the
cases whose speed readings the tracks find off by 2.5 % or more (faulty, the queue, the
congested preset with faults, dense traffic with a 6 % speed error); on the others it is off.
Counting a link's anchor in its track's evidence (`confirmation.py`, session 8) kept a few
anchored window-cut pairs of the featured stop-and-go case as targets.
Drawing the lanes' chains again with lengths averaged along the tracks (`anchors.track_lengths`,
session 9) moved the featured cases whose anchors weigh in (the queue, stop-and-go, and the
bottleneck, pinned since), and the chains' heavy-tailed steps where lengths pin them
(`chains.step_score`, the same day) all four featured cases but free flow.
When a change of the METHOD moves a grouping on purpose, print the new digests with
`python -m tests.association.associators.assignment.test_pinned_groupings` and say why in the
commit.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np
import pytest

from roadlink.association.associators.assignment import AssignmentAssociator
from roadlink.association.csvio import read_detections_csv

DATA = Path(__file__).parents[3] / "data"

PINNED: dict[tuple[str, tuple[tuple[str, float], ...]], str] = {
    ("sumo/sumo-bottleneck", ()): "d999ab41d7b0bb9b",
    ("sumo/sumo-dense", ()): "2e1deaef27097e97",
    ("sumo/sumo-faulty", ()): "1fc6205d46f013ab",
    ("sumo/sumo-freeflow", ()): "4410844f39819332",
    ("sumo/sumo-irregular", ()): "fdf5a26e3eca1905",
    ("sumo/sumo-queue", ()): "5eb806d80a96ec8c",
    ("sumo/sumo-stopgo", ()): "6a13eacd4cb1b103",
    ("sumo-features/sumo-bottleneck", ()): "4f69cbaa0e513348",
    ("sumo-features/sumo-dense-speed6", ()): "4a80a88cc0d8a09e",
    ("sumo-features/sumo-freeflow", ()): "2dc3133c2c5d6eae",
    ("sumo-features/sumo-queue", ()): "a97b900b503f4e3e",
    ("sumo-features/sumo-stopgo", ()): "23f41c36209ac14d",
    ("presets/congested-seed0-faults", ()): "5b9ba8e3942a7abf",
    ("presets/large-seed1", ()): "377c5807b2719eac",
    ("presets/small-seed2-faults", ()): "e5e850590ebb7773",
    ("sumo/sumo-dense", (("refine_sweeps", 0),)): "dfeee259de70ab93",
    ("sumo/sumo-dense", (("min_confidence", 0.5),)): "05bb53636426d207",
    ("sumo/sumo-faulty", (("em_rounds", 0),)): "910474fd6069ea5c",
    ("sumo-features/sumo-stopgo", (("lane_anchors", False),)): "ce6123aa866b1b6c",
    ("sumo-features/sumo-queue", (("feature_weight", 0.0),)): "9b66328eb783f22a",
}


def digest(case: str, params: tuple[tuple[str, float], ...]) -> str:
    detections = read_detections_csv((DATA / f"{case}.csv").read_bytes()).without_labels()
    grouping = AssignmentAssociator(**dict(params)).group(detections)
    return hashlib.sha256(np.ascontiguousarray(grouping, dtype=np.int64).tobytes()).hexdigest()[:16]


@pytest.mark.parametrize(("case", "params"), list(PINNED), ids=lambda v: str(v))
def test_the_grouping_is_the_pinned_one(case: str, params: tuple[tuple[str, float], ...]) -> None:
    assert digest(case, params) == PINNED[case, params]


if __name__ == "__main__":
    for case, params in PINNED:
        print(f'    ("{case}", {params!r}): "{digest(case, params)}",')
