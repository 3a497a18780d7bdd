"""benchmarks/queue_travel_times.py: the claim docs/sumo.md makes from it, on the committed case."""

import matplotlib.image
import numpy as np

from benchmarks import queue_travel_times as study
from roadlink.association.csvio import read_detections_csv


def test_the_clock_predicts_queued_travel_times_and_the_speeds_free_flowing_ones():
    d = read_detections_csv(study.CASE.read_text())
    rows = {
        start: (speed, kinematic, clock)
        for start, speed, kinematic, clock, _ in study.segment_spreads(d)
    }
    speed, kinematic, clock = rows[200.0]  # free flow upstream of the queue
    assert speed > 25 and kinematic < 0.02 < clock
    for start in (1200.0, 1700.0, 1950.0):  # inside the queue, and the single lane after it
        speed, kinematic, clock = rows[start]
        assert speed < 15 and clock < kinematic / 3


def test_the_neighbours_median_never_uses_the_element_itself():
    series = np.array([0.0, 0.0, 0.0, 100.0, 0.0, 0.0, 0.0])
    assert study.neighbours_median(series, 1)[3] == 0.0
    assert study.neighbours_median(np.arange(5.0), 1).tolist() == [0.5, 1.0, 2.0, 3.0, 3.5]


def test_the_figure_is_written(tmp_path):
    d = read_detections_csv(study.CASE.read_text())
    out = tmp_path / "queue.png"
    study.draw(d, [0, 4], out)
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    pixels = matplotlib.image.imread(out)[..., :3]
    height, width, _ = pixels.shape
    assert width > 600 and height > 300
    # Drawn, not blank: a fair share of the canvas is ink, in several colours (one per vehicle).
    ink = pixels.min(axis=2) < 0.9
    assert ink.mean() > 0.01
    assert len(np.unique((pixels[ink] * 8).astype(int), axis=0)) >= 4
