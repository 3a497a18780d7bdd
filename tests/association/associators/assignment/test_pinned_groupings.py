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
Costing the batch's time window (`assignment/edges.py`, session 11: a detection near its edge
may have no partner inside it) moved every case with queues or faults; learning from the tracks
that hold an anchored link however short (`learning.confident_detections`, the same session) the
featured queue, stop-and-go and bottleneck; joining fragments at the forward pass's gate where the
anchors weigh (`refine.fragment_ends`, the same session) the featured queue, stop-and-go and
bottleneck.
Centring each block's kinematic term on its own first chain where lengths pin the chains, and
chaining each lane to the lane its vehicles reach (`first_chains.recentred`,
`anchors.lane_destinations`, session 12) moved the featured queue, stop-and-go and bottleneck.
Costing a skip in a lane's chain by the segment's learned lane changes (`anchors.skip_costs`,
session 13) moved the featured bottleneck, queue, stop-and-go and dense traffic, and the same
costs in the loose first chains (`first_chains.loose_chains`) the featured queue.
A copy of a passage joining its twin's target, and a report in another lane or of another class
no longer taken for a copy (`duplicates.py`, session 21), moved the cases with copies (faulty
traffic, the presets with faults) and a few where a vehicle was left out beside another of its
speed (stop-and-go), or, with lanes, could now start its track (the featured queue and
stop-and-go).
Reading the speeds' error as the smaller of the changes as they are and about their segments'
means (`pace.reading_error`, session 22: a sensor's calibration is no error of every reading)
moved the congested preset with faults, whose slow zone's mean changes had read as error.
A copy that copies a passage, never another copy, speeds under the floor never alike, and a
report sent again never a vehicle of its own (`duplicates.py`, session 23: a stuck detector's
repeats, a crawl's floored speeds and a batch sent twice had chained into one target) moved
the cases with copies: faulty traffic and the congested preset with faults.
The batch's window taken as every sensor's (`edges.py`, session 23: a sensor that fell quiet
part-way had ended its upstream neighbour's window) moved the cases with queues, whose window
edges cost most, and the faulty ones.
A sparse sensor (`Sensors.sparse`, session 24: one that stopped reporting early in a busy batch,
or started late) tested like a busy one in the prior, its typical speed its neighbours', its
segments keeping the prior's travel time, moved the queue without features, whose sensor at
700 m saw 22 vehicles in the queue against its neighbours' 53 and 82 (33.8 -> 35.3 %).
A vehicle a queue held between two sensors past the batch's end, told by the sensors' counts or
by the travel times the segment's tracks took, and the detections of a track too weak to be a
target judged one by one (`confirmation.py`, session 26: queued vehicles had been left out as
false alarms) moved the queue and the bottleneck with and without features and the featured
stop-and-go.
No link over a sensor inside a queue's silence (`silences.py`, session 27: vehicles waiting
behind a sensor the queue stood still on had been linked over it, as if it had missed them) moved
the queue with and without features.
Lane order at the re-pairing's boundaries (`lane_inversions.py`, session 31: two successive
links between the same lanes that cross are exchanged where the segment's tracks say crossing
is rarer than the exchange costs) moved the featured bottleneck, queue and stop-and-go.
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
    ("sumo/sumo-bottleneck", ()): "8d2b3d054bc83689",
    ("sumo/sumo-dense", ()): "6149ef2dcb2d64fa",
    ("sumo/sumo-faulty", ()): "df39f89e94978804",
    ("sumo/sumo-freeflow", ()): "4410844f39819332",
    ("sumo/sumo-irregular", ()): "fdf5a26e3eca1905",
    ("sumo/sumo-queue", ()): "254d24b7b6eae7e2",
    ("sumo/sumo-stopgo", ()): "48b3bd2e1f9d1800",
    ("sumo-features/sumo-bottleneck", ()): "d8deea06ce4548db",
    ("sumo-features/sumo-dense-speed6", ()): "6116fe445fa86301",
    ("sumo-features/sumo-freeflow", ()): "2dc3133c2c5d6eae",
    ("sumo-features/sumo-queue", ()): "389ccdb077fca92d",
    ("sumo-features/sumo-stopgo", ()): "59fe90abb81d20cc",
    ("presets/congested-seed0-faults", ()): "5bce0f4289dd9115",
    ("presets/large-seed1", ()): "377c5807b2719eac",
    ("presets/small-seed2-faults", ()): "d3bc59c130bfe561",
    ("sumo/sumo-dense", (("refine_sweeps", 0),)): "dfeee259de70ab93",
    ("sumo/sumo-dense", (("min_confidence", 0.5),)): "c7d39e77edf96970",
    ("sumo/sumo-faulty", (("em_rounds", 0),)): "2d410fa2b3c3b398",
    ("sumo-features/sumo-stopgo", (("lane_anchors", False),)): "7cef67d235fa5c85",
    ("sumo-features/sumo-queue", (("feature_weight", 0.0),)): "6ac632b22f4232a3",
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
