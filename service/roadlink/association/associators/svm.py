"""The paper's supervised associators: one-vs-all SVMs, linear and quadratic.

An SVM needs labelled detections to learn from. Every labelled detection gets an out-of-fold
prediction from stratified k-fold cross-validation (the paper's protocol, k = 10), so the scores
measure generalisation, not memory; unlabelled detections are predicted by a model trained on all
labelled ones. Detections predicted as clutter are left unassigned. Beyond the paper,
`use_length` adds the measured vehicle length as a third feature (`lengths`).
"""

from __future__ import annotations

import warnings
from typing import TYPE_CHECKING, ClassVar

import numpy as np
from pydantic import Field

from roadlink.association.associators.base import (
    AssociationError,
    Associator,
    AssociatorParams,
    Progress,
)
from roadlink.association.associators.lengths import with_length
from roadlink.association.backprojection import backprojected_features
from roadlink.association.detections import CLUTTER, Detections, IntArray

if TYPE_CHECKING:
    from sklearn.pipeline import Pipeline


class SVMParams(AssociatorParams):
    backproject: bool = Field(
        default=True,
        description="Classify on time back-projected to the first sensor (the "
        "paper's pre-processing); false classifies the raw (velocity, timestamp) points.",
    )
    C: float = Field(default=1.0, gt=0, le=1e6, description="Soft-margin penalty of the SVMs.")
    folds: int = Field(
        default=10,
        ge=2,
        le=100,
        description="Folds of the stratified cross-validation that "
        "predicts the labelled detections (fewer when a target has fewer detections).",
    )
    seed: int = Field(default=0, ge=0, description="Seed of the fold shuffling.")
    use_length: bool = Field(
        default=False,
        description="Also classify on the measured vehicle length (beyond the paper; "
        "standardised as the other features are, so it needs no weight); a missing length is "
        "imputed with the median of its sensor's measured lengths.",
    )


class _OneVsAllSVM(Associator):
    needs_labels: ClassVar[bool] = True
    imports_on_first_use: ClassVar[tuple[str, ...]] = (
        "sklearn.model_selection",
        "sklearn.multiclass",
        "sklearn.pipeline",
        "sklearn.preprocessing",
        "sklearn.svm",
    )
    Params = SVMParams
    params: SVMParams
    kernel: ClassVar[dict[str, object]]

    def _model(self) -> Pipeline:
        # Standardised features, as MATLAB's Classification Learner (which the paper's
        # "Linear SVM" / "Quadratic SVM" and 10-fold protocol come from) does by default.
        # Imported here: scikit-learn takes seconds to import, which a process that runs
        # another associator (or none) need not pay.
        from sklearn.multiclass import OneVsRestClassifier
        from sklearn.pipeline import make_pipeline
        from sklearn.preprocessing import StandardScaler
        from sklearn.svm import SVC

        svc = SVC(C=self.params.C, **self.kernel)
        return make_pipeline(StandardScaler(), OneVsRestClassifier(svc))

    def group(self, detections: Detections, progress: Progress | None = None) -> IntArray:
        labelled = detections.labelled
        if not labelled.any():
            raise AssociationError(
                f"'{self.name}' is supervised: label some detections with their true target "
                "(the 'target' field or CSV column) so it has something to learn from"
            )
        points = backprojected_features(detections, self.params.backproject)
        if self.params.use_length:
            points = with_length(points, detections)
        names, y = np.unique(detections.target[labelled].astype(str), return_inverse=True)
        if names.size < 2:
            raise AssociationError(f"'{self.name}' needs at least two distinct labels to learn")
        predicted = np.empty(len(detections), dtype=np.int64)
        predicted[labelled] = self._cross_validated(points[labelled], y, progress)
        if not labelled.all():
            model = self._model().fit(points[labelled], y)
            predicted[~labelled] = model.predict(points[~labelled])
        clutter = np.flatnonzero(names == CLUTTER)
        if clutter.size:
            predicted[predicted == clutter[0]] = -1
        return predicted

    def _cross_validated(
        self, points: np.ndarray, y: IntArray, progress: Progress | None
    ) -> IntArray:
        largest_class = int(np.bincount(y).max())
        if largest_class < 2:
            raise AssociationError(
                f"'{self.name}' cross-validates its predictions, so some label must mark at "
                "least two detections"
            )
        from sklearn.model_selection import StratifiedKFold

        folds = StratifiedKFold(
            n_splits=min(self.params.folds, largest_class),
            shuffle=True,
            random_state=self.params.seed,
        )
        out = np.empty(y.size, dtype=np.int64)
        with warnings.catch_warnings():
            # A target with fewer detections than folds is expected (missed detections).
            warnings.filterwarnings(
                "ignore", message="The least populated class", category=UserWarning
            )
            splits = list(folds.split(points, y))
        for done, (train, test) in enumerate(splits, start=1):
            out[test] = self._model().fit(points[train], y[train]).predict(points[test])
            if progress:
                progress(done / len(splits))
        return out


class LinearSVMAssociator(_OneVsAllSVM):
    name: ClassVar[str] = "svm-linear"
    description: ClassVar[str] = (
        "The paper's linear SVM, one-vs-all, in (velocity, back-projected time) space, with "
        "use_length the measured length too. Supervised: learns from labelled detections; "
        "labelled ones are predicted out-of-fold."
    )
    kernel: ClassVar[dict[str, object]] = {"kernel": "linear"}


class QuadraticSVMAssociator(_OneVsAllSVM):
    name: ClassVar[str] = "svm-quadratic"
    description: ClassVar[str] = (
        "The paper's quadratic SVM (polynomial kernel (1 + x.y)^2), one-vs-all, in (velocity, "
        "back-projected time) space, with use_length the measured length too. Supervised: "
        "learns from labelled detections."
    )
    kernel: ClassVar[dict[str, object]] = {
        "kernel": "poly",
        "degree": 2,
        "gamma": 1.0,
        "coef0": 1.0,
    }
