"""The association result: targets with their detections, unassigned, metrics (the document is
`AssociationResultRead` in roadlink/api/schemas.py and openapi/openapi.json)."""

from __future__ import annotations

from collections import Counter
from collections.abc import Callable, Mapping
from dataclasses import dataclass, replace
from typing import Any

import numpy as np

from roadlink.association.backprojection import backproject_times
from roadlink.association.csvio import FEATURE_COLUMNS
from roadlink.association.detections import Detections, FloatArray, IntArray, feature_arrays
from roadlink.association.matrix_text import matrix_csv
from roadlink.association.scores import Metrics, Truth, score_grouping, truth_of


@dataclass(frozen=True, eq=False)
class AssociationResult:
    """Detections grouped into targets.

    `groups[i]` is the target index of detection i in `targets_order` terms: targets are numbered
    0..n_targets-1 in the order they pass the reference sensor; -1 is unassigned.
    `effective_params` are the parameters the associator ran with, for an associator that adapts
    `params` (the ones asked for) to the detections; None for one that runs with them as given.
    `link_confidence[i]` is the approximate probability that the link from the previous
    detection of i's target to i is right (NaN for a target's first detection and for
    unassigned ones), from an associator that builds targets from links; else None.
    `warnings` are what the associator found wrong with the detectors (a sensor whose clock or
    speed calibration is off), for whoever keeps them.
    """

    associator: str
    params: dict[str, Any]
    detections: Detections
    groups: IntArray
    metrics: Metrics | None
    effective_params: dict[str, Any] | None = None
    link_confidence: FloatArray | None = None
    warnings: tuple[str, ...] = ()

    @property
    def n_targets(self) -> int:
        return int(self.groups.max(initial=-1)) + 1

    def scored(self, truth: Truth | None = None) -> AssociationResult:
        """This result with its metrics: what `build_result(..., scored=False)` left for later.
        `truth`, when given, is `truth_of_detections(self.detections)`, read beforehand."""
        known = truth_of_detections(self.detections) if truth is None else truth
        return replace(self, metrics=score_grouping(self.groups, known))

    def target_members(self) -> list[IntArray]:
        """Detection indices of each target, ordered by position (then time)."""
        assigned = np.flatnonzero(self.groups >= 0)
        if not assigned.size:
            return []
        d = self.detections
        order = assigned[
            road_order(self.groups[assigned], d.position[assigned], d.timestamp[assigned])
        ]
        bounds = (np.flatnonzero(np.diff(self.groups[order])) + 1).tolist()
        # Slices, not `np.split`, which costs a `swapaxes` per target (20,000 at 10^6).
        return [order[a:b] for a, b in zip([0, *bounds], [*bounds, order.size], strict=True)]

    def target_confidence(self, members: IntArray) -> float | None:
        """The approximate probability that every link of a target is right: the product of
        its links' confidences (1 for a target of one detection); None without confidences."""
        if self.link_confidence is None:
            return None
        links = self.link_confidence[members]
        return float(np.prod(links[np.isfinite(links)]))

    def target_confidences(self, members: list[IntArray]) -> list[float | None]:
        """`target_confidence` of each of the targets `members` (none empty), at once: one
        product per target over its links in the same order (a missing link counts as 1.0,
        by which a product is unchanged), so the same floats."""
        if self.link_confidence is None or not members:
            return [None] * len(members)
        return self.link_products(np.concatenate(members), np.array([m.size for m in members]))

    def link_products(self, order: IntArray, sizes: IntArray) -> list[float | None]:
        """`target_confidences` of the targets whose members, each in `target_members`' order,
        are `order` cut into runs of `sizes` (none 0): the same floats, by the same steps."""
        assert self.link_confidence is not None
        links = self.link_confidence[order]
        links = np.where(np.isfinite(links), links, 1.0)
        return list(np.multiply.reduceat(links, np.cumsum(sizes) - sizes).tolist())

    def to_dict(self) -> dict[str, Any]:
        """The JSON document (`effective_params` only from an associator that adapts them;
        confidences only from one that builds targets from links)."""
        rows = _detection_rows(self.detections, self.detections.features)
        if self.link_confidence is not None:
            # Each row appears once in the document: a target's detection carries the
            # confidence of the link into it (none for its first), an unassigned one none.
            linked = np.flatnonzero((self.groups >= 0) & ~np.isnan(self.link_confidence))
            for i, link in zip(linked.tolist(), self.link_confidence[linked].tolist(), strict=True):
                rows[i]["link_confidence"] = link
        return self.document(lambda members: [rows[i] for i in members.tolist()])

    def document(self, detections_of: Callable[[IntArray], Any]) -> dict[str, Any]:
        """The JSON document with each target's detections, then the unassigned ones, as
        `detections_of` gives them from their indices, called in document order (`to_dict`:
        the row objects; `result_text`: a place for their text)."""
        features = self.detections.features
        members = self.target_members()
        adapted = (
            {} if self.effective_params is None else {"effective_params": self.effective_params}
        )
        warned = {"warnings": list(self.warnings)} if self.warnings else {}
        return {
            "associator": self.associator,
            "params": self.params,
            **adapted,
            **warned,
            "n_detections": len(self.detections),
            "n_targets": self.n_targets,
            "targets": [
                self._target_dict(k, of_target, confidence, detections_of, features)
                for k, (of_target, confidence) in enumerate(
                    zip(members, self.target_confidences(members), strict=True)
                )
            ],
            "unassigned": detections_of(np.flatnonzero(self.groups < 0)),
            "metrics": None if self.metrics is None else self.metrics.to_dict(),
        }

    def _target_dict(
        self,
        k: int,
        members: IntArray,
        confidence: float | None,
        detections_of: Callable[[IntArray], Any],
        features: tuple[str, ...],
    ) -> dict[str, Any]:
        summary = self.target_features(members, features)
        if confidence is None or self.link_confidence is None:
            return {"target": f"T{k + 1}", **summary, "detections": detections_of(members)}
        return {
            "target": f"T{k + 1}",
            "confidence": confidence,
            **summary,
            "detections": detections_of(members),
        }

    def target_features(self, members: IntArray, features: tuple[str, ...]) -> dict[str, Any]:
        """What a target's detections say of the vehicle, for the `features` the input reports
        (`Detections.features`; none without them, so such results stay as they were):
        `length`, the median of its measured lengths (one bad loop reading does not move it),
        and `vehicle_class`, its most common reported class (a tie goes to the class reported
        first along the road); None where none of its detections reports the feature."""
        d = self.detections
        summary: dict[str, Any] = {}
        if "length" in features:
            lengths = d.length[members]
            measured = lengths[~np.isnan(lengths)]
            summary["length"] = float(np.median(measured)) if measured.size else None
        if "vehicle_class" in features:
            counts = Counter(c for c in d.vehicle_class[members].tolist() if c is not None)
            summary["vehicle_class"] = counts.most_common(1)[0][0] if counts else None
        return summary

    def to_matrix_csv(self) -> str:
        """The paper's X'': one row per target, per sensor its detection id, velocity and time.

        A cell holding several detections (possible with K-means) lists them separated by ';'.
        From an associator that builds targets from links, a `confidence` column follows the
        target's name, and each sensor has a fourth column, the confidence of the link into its
        detection (empty for the target's first). Each detector feature the input reports
        (`lane`, `length`, `vehicle_class`) adds one more column per sensor, empty where a
        detection does not report it; without features the matrix is as it always was.
        """
        return matrix_csv(self)


def result_from_dict(
    document: Mapping[str, Any], labels: Mapping[str, str | None] | None = None
) -> AssociationResult:
    """The result that `AssociationResult.to_dict` wrote `document` from, rebuilt.

    The document names every detection once, with its group, but not its true label: `labels`
    gives them by detection id (ids it lacks are unlabelled), and the result is scored again, so
    that the wrongly grouped detections can be told. Detections come back target by target (each
    ordered by position) and then the unassigned ones; `groups` keeps the document's numbering,
    so target "T3" is the same target in both.
    """
    labels = labels or {}
    rows: list[Mapping[str, Any]] = []
    groups: list[int] = []
    for k, target in enumerate(document["targets"]):
        rows.extend(target["detections"])
        groups.extend([k] * len(target["detections"]))
    rows.extend(document["unassigned"])
    groups.extend([-1] * len(document["unassigned"]))
    n = len(rows)
    has_links = any("confidence" in target for target in document["targets"])
    link_confidence = (
        np.array([r.get("link_confidence", np.nan) for r in rows], dtype=np.float64).reshape(n)
        if has_links
        else None
    )
    ids = np.array([str(r["detection_id"]) for r in rows], dtype=object).reshape(n)
    # A feature's key is on every detection when the input reported it, on none otherwise.
    features = {
        name: [r.get(name) for r in rows]
        for name in FEATURE_COLUMNS
        if any(name in r for r in rows)
    }
    detections = Detections(
        position=np.array([r["position"] for r in rows], dtype=np.float64).reshape(n),
        velocity=np.array([r["velocity"] for r in rows], dtype=np.float64).reshape(n),
        timestamp=np.array([r["timestamp"] for r in rows], dtype=np.float64).reshape(n),
        sensor_id=np.array([str(r["sensor_id"]) for r in rows], dtype=object).reshape(n),
        detection_id=ids,
        target=np.array([labels.get(i) for i in ids], dtype=object).reshape(n),
        **feature_arrays(**features),
    )
    group_array = np.array(groups, dtype=np.int64).reshape(n)
    effective = document.get("effective_params")
    return AssociationResult(
        associator=str(document["associator"]),
        params=dict(document["params"]),
        detections=detections,
        groups=group_array,
        metrics=score_grouping(group_array, _labels(detections)),
        effective_params=None if effective is None else dict(effective),
        link_confidence=link_confidence,
        warnings=tuple(str(w) for w in document.get("warnings", ())),
    )


def build_result(
    detections: Detections,
    groups: IntArray,
    associator: str,
    params: dict[str, Any],
    effective_params: dict[str, Any] | None = None,
    link_confidence: FloatArray | None = None,
    *,
    scored: bool = True,
    warnings: tuple[str, ...] = (),
) -> AssociationResult:
    """Renumber groups by the time each target passes the reference sensor, and score them
    (unless not `scored`: then the metrics are None until `AssociationResult.scored`).

    A target's passing time is the back-projected time of its detection nearest the reference
    sensor (its own passing time, when it was seen there).
    """
    groups = np.asarray(groups, dtype=np.int64)
    if groups.shape != (len(detections),):
        raise ValueError(f"{len(detections)} detections but {groups.size} group indices")
    renumbered = np.full(groups.size, -1, dtype=np.int64)
    assigned = np.flatnonzero(groups >= 0)
    if assigned.size:
        times = backproject_times(
            detections.position,
            detections.velocity,
            detections.timestamp,
            detections.reference_position,
        )
        # Per group, its detection with the smallest position (first along the road).
        order = assigned[np.lexsort((detections.position[assigned], groups[assigned]))]
        labels, first = np.unique(groups[order], return_index=True)
        rank = np.empty(labels.size, dtype=np.int64)
        rank[np.argsort(times[order[first]], kind="stable")] = np.arange(labels.size)
        renumbered[assigned] = rank[np.searchsorted(labels, groups[assigned])]
    return AssociationResult(
        associator=associator,
        params=params,
        detections=detections,
        groups=renumbered,
        metrics=score_grouping(renumbered, _labels(detections)) if scored else None,
        effective_params=effective_params,
        link_confidence=link_confidence,
        warnings=warnings,
    )


def road_order(groups: IntArray, position: FloatArray, timestamp: FloatArray) -> IntArray:
    """The order `np.lexsort((timestamp, position, groups))` gives (stable: equal rows keep
    their order), sorted by one integer key, group and position's rank, where lexsort makes
    three stable passes: twice its speed. Rows of one group at one position (a duplicate, say:
    few) are then ordered by time among themselves."""
    distinct, rank = np.unique(position, return_inverse=True)  # -0.0 and 0.0 one rank
    key = groups.astype(np.int64) * distinct.size + rank.reshape(-1)
    order = np.argsort(key, kind="stable")
    keys = key[order]
    tied = np.flatnonzero(keys[1:] == keys[:-1])
    if tied.size:
        in_run = np.zeros(keys.size, dtype=bool)
        in_run[tied] = in_run[tied + 1] = True
        runs = order[in_run]  # each run's rows together, in their order
        order[in_run] = runs[np.lexsort((timestamp[runs], keys[in_run]))]
    return order


def _detection_rows(d: Detections, features: tuple[str, ...]) -> list[dict[str, Any]]:
    """Every detection as its result-JSON object, in input order: with a key for each feature
    the input reports (null where this detection does not), and none without features."""
    rows = _measurement_rows(d)
    for name in features:
        for row, value in zip(rows, d.feature_values(name), strict=True):
            row[name] = value
    return rows


def _measurement_rows(d: Detections) -> list[dict[str, Any]]:
    return [
        {
            "detection_id": detection_id,
            "sensor_id": sensor_id,
            "position": position,
            "velocity": velocity,
            "timestamp": timestamp,
        }
        for detection_id, sensor_id, position, velocity, timestamp in zip(
            d.detection_id.tolist(),
            d.sensor_id.tolist(),
            d.position.tolist(),
            d.velocity.tolist(),
            d.timestamp.tolist(),
            strict=True,
        )
    ]


def truth_of_detections(detections: Detections) -> Truth:
    """The detections' true labels as the scoring reads them; they do not depend on the
    grouping, so a caller may read them while the detections are associated (the CLI does)."""
    return truth_of(_labels(detections))


def _labels(detections: Detections) -> Any:
    """The labels as the scoring takes them best: the CSV parser's column, when it made one."""
    parsed = detections.parsed_texts("target")
    return detections.target if parsed is None else parsed
