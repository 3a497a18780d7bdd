"""The paper's comparison study: every associator, with and without back-projection, on every
preset, over many seeds; the accuracy of each, as mean and spread."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from roadlink.association.associators import ASSOCIATORS
from roadlink.association.pipeline import associate
from roadlink.simulation.config import preset
from roadlink.simulation.generate import simulate


@dataclass(frozen=True)
class Variant:
    """An associator run one way: e.g. K-means++ on raw (not back-projected) data."""

    associator: str
    backproject: bool | None  # None: the associator has no such switch

    @property
    def label(self) -> str:
        return self.associator if self.backproject in (None, True) else f"{self.associator} (raw)"

    @property
    def params(self) -> dict[str, object]:
        return {} if self.backproject is None else {"backproject": self.backproject}


@dataclass(frozen=True)
class StudyRow:
    """Accuracy of one variant on one preset, over all seeds."""

    preset: str
    variant: Variant
    accuracies: tuple[float, ...]

    @property
    def mean(self) -> float:
        return float(np.mean(self.accuracies))

    @property
    def std(self) -> float:
        return float(np.std(self.accuracies))

    @property
    def minimum(self) -> float:
        return float(np.min(self.accuracies))


def study_variants(associators: Sequence[str] | None = None) -> list[Variant]:
    """Every associator; with a `backproject` switch, also on raw data (the paper's baseline)."""
    variants = []
    for name in associators or list(ASSOCIATORS):
        if "backproject" in ASSOCIATORS[name].Params.model_fields:
            variants += [Variant(name, True), Variant(name, False)]
        else:
            variants.append(Variant(name, None))
    return variants


def run_study(
    presets: Sequence[str],
    variants: Sequence[Variant],
    seeds: int,
    on_step: Callable[[], None] | None = None,
) -> list[StudyRow]:
    """Run every variant on the same simulated data sets (seeds 0..seeds-1 of each preset)."""
    rows = []
    for name in presets:
        config = preset(name)
        datasets = [simulate(config, seed=seed).detections for seed in range(seeds)]
        for variant in variants:
            accuracies = []
            for detections in datasets:
                metrics = associate(detections, variant.associator, variant.params).metrics
                assert metrics is not None  # simulated detections are always labelled
                accuracies.append(metrics.accuracy)
                if on_step:
                    on_step()
            rows.append(StudyRow(name, variant, tuple(accuracies)))
    return rows
