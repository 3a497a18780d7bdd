"""K-means and K-means++ (`associators/kmeans.py`): the target count, and the seeding."""

import numpy as np

from roadlink.association import associate
from roadlink.association.associators.kmeans import estimate_target_count, kmeanspp_centres
from roadlink.simulation import preset, simulate


def paper_data(name="large", seed=0, **overrides):
    return simulate(preset(name, **overrides), seed=seed).detections


def test_kmeans_estimates_the_target_count_from_detections_per_sensor():
    assert estimate_target_count(paper_data()) == 10
    assert estimate_target_count(paper_data("large", miss_probability=0.1, seed=1)) in (9, 10)
    result = associate(paper_data(), "kmeans++")
    assert result.n_targets == 10
    assert associate(paper_data(), "kmeans++", {"n_targets": 4}).n_targets == 4


def test_kmeanspp_seeding_draws_in_proportion_to_squared_distance():
    # Points 0, 1 and 3 on a line: once the first centre is at 0, the next is 1 with
    # probability 1/10 and 3 with probability 9/10.
    points = np.array([[0.0], [1.0], [3.0]])
    second = []
    for seed in range(4000):
        centres = kmeanspp_centres(points, 2, np.random.default_rng(seed))
        if centres[0, 0] == 0.0:
            second.append(centres[1, 0])
    share_of_far = np.mean(np.array(second) == 3.0)
    assert 0.86 < share_of_far < 0.94
    assert 0.0 not in second
