"""`assignment` for live steps (`roadlink.association.live_assignment`): without a model it
groups exactly as the offline associator and keeps what it learned; with an earlier step's
model it links once, skips the prior and the learning, and scores as offline; a model learned
on other sensors, features or parameters, or RELEARN_SECONDS of data ago, is learned again; a
model learned from too few links is not kept."""

from __future__ import annotations

from collections.abc import Callable
from types import ModuleType
from typing import Any

import numpy as np
import pytest

from roadlink.association import live_assignment
from roadlink.association.associators.assignment import (
    AssignmentAssociator,
    AssignmentParams,
    associator,
)
from roadlink.association.detections import Detections
from roadlink.association.live_assignment import Models, associate_window
from roadlink.association.scores import score_grouping
from roadlink.simulation import preset, simulate
from tests.helpers import with_features


def _traffic(features: bool = False, seed: int = 5) -> Detections:
    config = preset("large", n_targets=120, start_time_range=(1.0, 240.0))
    d = simulate(config, seed=seed).detections
    return with_features(d) if features else d


def _window(d: Detections, start: float, end: float) -> Detections:
    return d.take(np.flatnonzero((d.timestamp >= start) & (d.timestamp < end)))


def _offline(d: Detections, params: AssignmentParams) -> tuple[np.ndarray, np.ndarray]:
    grouper = AssignmentAssociator(params)
    groups = grouper.group(d.without_labels())
    return groups, grouper.link_confidence


def _accuracy(d: Detections, groups: np.ndarray) -> float:
    metrics = score_grouping(groups, d.target)
    assert metrics is not None
    return metrics.accuracy


def _counting(monkeypatch: pytest.MonkeyPatch, module: ModuleType, name: str) -> list[int]:
    """Count the calls of the stage `name` as `module` (the live step's, or the associator's
    loop that it shares) calls it."""
    calls: list[int] = []
    stage: Callable[..., Any] = getattr(module, name)

    def counted(*args: Any, **kwargs: Any) -> Any:
        calls.append(1)
        return stage(*args, **kwargs)

    monkeypatch.setattr(module, name, counted)
    return calls


@pytest.mark.parametrize("features", [False, True])
def test_without_a_model_a_window_is_grouped_as_the_offline_associator_groups_it(
    features: bool,
) -> None:
    d = _window(_traffic(features), 0.0, 150.0)
    params = AssignmentParams()
    groups, confidence, learned = associate_window(d.without_labels(), params, 150.0, None)
    offline_groups, offline_confidence = _offline(d, params)
    np.testing.assert_array_equal(groups, offline_groups)
    np.testing.assert_array_equal(confidence, offline_confidence)  # NaN where no link
    assert learned is not None and learned.clock == 150.0


def test_a_window_sent_twice_is_grouped_as_sent_once() -> None:
    # A gateway that sends its reports again: each report is grouped once and its repeat
    # joins it, as offline.
    d = _window(_traffic(), 0.0, 150.0).without_labels()
    twice = d.take(np.r_[np.arange(len(d)), np.arange(len(d))])
    params = AssignmentParams()
    groups, confidence, _ = associate_window(d, params, 150.0, None)
    both, both_confidence, learned = associate_window(twice, params, 150.0, None)
    np.testing.assert_array_equal(both, np.r_[groups, groups])
    np.testing.assert_array_equal(both_confidence[: len(d)], confidence)
    assert np.isnan(both_confidence[len(d) :]).all() and learned is not None


@pytest.mark.parametrize("features", [False, True])
def test_with_the_last_steps_model_a_window_is_linked_once(
    features: bool, monkeypatch: pytest.MonkeyPatch
) -> None:
    d = _traffic(features)
    params = AssignmentParams()
    _, _, learned = associate_window(_window(d, 0.0, 150.0).without_labels(), params, 150.0, None)
    priors = _counting(monkeypatch, live_assignment, "segment_prior")
    passes = _counting(monkeypatch, associator, "build_tracks")
    later = _window(d, 90.0, 260.0).without_labels()
    _, _, following = associate_window(later, params, 260.0, learned)
    assert priors == []  # the prior is the earlier step's
    assert len(passes) == (2 if features else 1)  # anchors need a pass without them
    assert following is learned


def test_with_the_last_steps_model_windows_score_as_offline() -> None:
    # Over several windows: one window of a hundred vehicles moves a point with one vehicle,
    # either way (the warm step is ahead of offline on some, behind on others).
    params = AssignmentParams()
    live, offline = [], []
    for seed in range(1, 6):
        d = _traffic(seed=seed)
        first = _window(d, 0.0, 150.0).without_labels()
        _, _, learned = associate_window(first, params, 150.0, None)
        later = _window(d, 90.0, 260.0)
        groups, _, _ = associate_window(later.without_labels(), params, 260.0, learned)
        live.append(_accuracy(later, groups))
        offline.append(_accuracy(later, _offline(later, params)[0]))
    assert np.mean(live) >= np.mean(offline) - 0.01


def test_a_model_is_learned_again_once_it_is_relearn_seconds_of_data_old(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    d = _window(_traffic(), 0.0, 150.0)
    params = AssignmentParams()
    _, _, learned = associate_window(d.without_labels(), params, 150.0, None)
    priors = _counting(monkeypatch, live_assignment, "segment_prior")
    learning = _counting(monkeypatch, associator, "learn_segments")
    later = 150.0 + live_assignment.RELEARN_SECONDS
    groups, _, following = associate_window(d.without_labels(), params, later, learned)
    assert len(priors) == 1 and learning  # a step with the kept model learns nothing
    assert following is not None and following is not learned and following.clock == later
    np.testing.assert_array_equal(groups, _offline(d, params)[0])


def test_a_model_learned_from_a_streams_first_seconds_is_not_kept() -> None:
    # 20 s of data: few vehicles have reached the far sensors yet.
    d = _window(_traffic(), 0.0, 20.0).without_labels()
    _, _, learned = associate_window(d, AssignmentParams(), 20.0, None)
    assert learned is None


@pytest.mark.parametrize("change", ["sensors", "params", "features"])
def test_a_model_learned_on_other_sensors_features_or_parameters_is_not_used(
    change: str,
) -> None:
    d = _window(_traffic(), 0.0, 150.0)
    params = AssignmentParams()
    _, _, learned = associate_window(d.without_labels(), params, 150.0, None)
    if change == "sensors":  # the farthest sensor reported nothing in this window
        d = d.take(np.flatnonzero(d.position < d.position.max()))
    elif change == "params":
        params = AssignmentParams(refine_sweeps=1)
    else:
        d = with_features(d)
    groups, confidence, _ = associate_window(d.without_labels(), params, 150.0, learned)
    offline_groups, offline_confidence = _offline(d, params)
    np.testing.assert_array_equal(groups, offline_groups)
    np.testing.assert_array_equal(confidence, offline_confidence)


def test_models_keep_the_most_recently_used_deployments() -> None:
    d = _window(_traffic(), 0.0, 150.0).without_labels()
    _, _, learned = associate_window(d, AssignmentParams(), 150.0, None)
    assert learned is not None
    models = Models(size=2)
    models.put("a", learned)
    models.put("b", learned)
    assert models.get("a") is learned  # a is now the most recent
    models.put("c", learned)
    assert models.get("b") is None
    assert models.get("a") is learned and models.get("c") is learned
    models.put("a", None)  # nothing worth keeping: the old model goes too
    assert models.get("a") is None
