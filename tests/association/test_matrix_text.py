"""The matrix is written alike every way: joined by polars (from `_POLARS_ROWS` detections),
joined from Python lists (below it), and cell by cell by csv.writer (where a cell holds
several detections or needs quoting): the same bytes for every result."""

import csv
import dataclasses
import io
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadlink.association import associate, matrix_text
from roadlink.association.csvio import (
    spreadsheet_safe,
    write_detections_csv,
)
from roadlink.association.detections import Detections
from roadlink.association.result import AssociationResult, build_result
from roadlink.simulation import preset, simulate
from tests.helpers import fast_read

WAYS = ("polars", "lists", "cell by cell")


def written(result: AssociationResult, way: str) -> str:
    """`result.to_matrix_csv()` written `way`."""
    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(matrix_text, "_POLARS_ROWS", 0 if way == "polars" else 10**9)
        if way == "cell by cell":
            patch.setattr(matrix_text, "_NEEDS_QUOTES", re.compile(r"|"))
        return result.to_matrix_csv()


def assert_written_alike(result: AssociationResult) -> str:
    texts = {way: written(result, way) for way in WAYS}
    assert texts["polars"] == texts["cell by cell"]
    assert texts["lists"] == texts["cell by cell"]
    return texts["polars"]


def grid(
    seed: int,
    n_targets: int,
    n_sensors: int,
    *,
    seen: float = 1.0,
    unassigned: float = 0.0,
    links: bool = True,
    features: bool = False,
    scale: float = 1.0,
    ids: list[str] | None = None,
) -> AssociationResult:
    """A result of `n_targets` targets along `n_sensors` sensors, each target seen at each
    sensor with probability `seen`, a share `unassigned` of the detections in no target,
    velocities and times times `scale` (1e-7: below 1e-4), a link's confidence NaN at random
    (and at each target's first), `features` reported by some detections, and `ids` for the
    first detections (the rest `d1`, `d2`, ...)."""
    rng = np.random.default_rng(seed)
    target, sensor = np.divmod(np.arange(n_targets * n_sensors), n_sensors)
    keep = rng.random(target.size) < seen
    target, sensor = target[keep], sensor[keep]
    n = target.size
    names = [f"S{k + 1}" for k in range(n_sensors)]
    detection_ids = [f"d{i + 1}" for i in range(n)]
    detection_ids[: len(ids or [])] = ids or []
    columns = {}
    if features:
        columns = {
            "lane": np.where(rng.random(n) < 0.3, np.nan, rng.integers(1, 4, n)),
            "length": np.where(rng.random(n) < 0.3, np.nan, rng.uniform(3, 20, n) * scale),
            "vehicle_class": [[None, "car", "truck", "=bus"][k] for k in rng.integers(0, 4, n)],
        }
    d = Detections.from_columns(
        100.0 * sensor,
        rng.uniform(10, 30, n) * scale,
        (10.0 * target + sensor + rng.random(n)) * scale,
        [names[k] for k in sensor],
        **columns,
    )
    d = dataclasses.replace(d, detection_id=np.array(detection_ids, dtype=object))
    groups = np.where(rng.random(n) < unassigned, -1, target)
    confidence = None
    if links:
        first = np.concatenate(([True], target[1:] != target[:-1]))
        confidence = np.where(first | (rng.random(n) < 0.2), np.nan, rng.random(n) * scale)
    return build_result(d, groups, "x", {}, link_confidence=confidence)


FORMULA_IDS = ["=1+1", "+a", "-b", "@c", "'d", "\te", "f=", "g'"]
QUOTED_IDS = ["a,b", 'c"d', "e\nf", "g\rh"]

CASES = {
    "full, with links": grid(1, 40, 6),
    "full, no links": grid(2, 40, 6, links=False),
    "sparse": grid(3, 60, 8, seen=0.6),
    "sparse, no links": grid(4, 60, 8, seen=0.6, links=False),
    "very sparse": grid(5, 80, 12, seen=0.1),
    "unassigned": grid(6, 50, 5, seen=0.8, unassigned=0.3),
    "features": grid(7, 40, 5, features=True),
    "features, sparse, unassigned": grid(8, 40, 5, seen=0.7, unassigned=0.2, features=True),
    "tiny floats": grid(9, 30, 4, scale=1e-7, features=True),
    "ids made spreadsheet safe": grid(10, 20, 4, seen=0.9, ids=FORMULA_IDS),
    "ids needing quotes": grid(11, 20, 4, ids=QUOTED_IDS),
    "one target": grid(12, 1, 7),
    "one target at one sensor": grid(13, 1, 1),
    "one sensor": grid(14, 30, 1),
    "many targets": grid(15, 3000, 5, seen=0.9, unassigned=0.05),
    "all unassigned": grid(16, 10, 3, unassigned=1.0),
}


@pytest.mark.parametrize("name", list(CASES))
def test_every_way_writes_the_same_matrix(name):
    assert_written_alike(CASES[name])


def results() -> list[AssociationResult]:
    featured = preset("medium", lanes=3, vehicle_lengths=True, vehicle_classes=True)
    faulty = preset("small", miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.05)
    # Read by the fast CSV reader: the ids are polars' column, taken as it is.
    read = fast_read(write_detections_csv(simulate(featured, seed=4).detections))
    assert read.parsed_texts("detection_id") is not None
    return [
        associate(simulate(preset("large"), seed=2).detections, "assignment", {}),
        associate(simulate(faulty, seed=2).detections, "assignment", {}),
        associate(simulate(featured, seed=2).detections, "assignment", {}),
        associate(simulate(featured, seed=2).detections, "kmeans", {}),  # cells of several
        associate(read, "assignment", {}),
    ]


@pytest.mark.parametrize("result", results())
def test_associated_results_write_the_same_matrix_every_way(result):
    assert_written_alike(result)


def test_plain_matrices_are_joined_not_written_cell_by_cell(monkeypatch):
    """Every case a fast way can write (a detection per cell at most, no cell to quote) it
    writes: the cell-by-cell writer is never called for it."""

    def refused(*args, **kwargs):
        raise AssertionError("written cell by cell")

    plain = [r for name, r in CASES.items() if name != "ids needing quotes"]
    expected = [written(r, "cell by cell") for r in plain]
    monkeypatch.setattr(matrix_text, "_cell_by_cell", refused)
    for way in ("polars", "lists"):
        assert [written(r, way) for r in plain] == expected


def test_a_cell_needing_quotes_is_quoted():
    matrix = assert_written_alike(CASES["ids needing quotes"])
    assert '"a,b"' in matrix and '"c""d"' in matrix


def test_ids_are_spreadsheet_safe():
    matrix = assert_written_alike(CASES["ids made spreadsheet safe"])
    cells = {cell for row in csv.reader(io.StringIO(matrix)) for cell in row}
    assert {spreadsheet_safe(i) for i in FORMULA_IDS} <= cells
    assert {"'=1+1", "''d", "'\te", "f=", "g'"} <= cells


def test_groups_numbered_with_gaps_are_rows_in_their_order():
    """A result built with groups other than 0, 1, ...: the k-th distinct group is row k."""
    result = grid(20, 12, 4, unassigned=0.1)
    for gapped in (3 * result.groups + 5, 1000 * result.groups):
        renumbered = dataclasses.replace(result, groups=np.where(result.groups >= 0, gapped, -1))
        assert assert_written_alike(renumbered) == written(result, "polars")


def test_sensors_reported_in_any_order():
    """Detections not sensor by sensor: the sensors' columns are found all the same."""
    result = grid(21, 30, 6, seen=0.8)
    mixed = np.random.default_rng(0).permutation(len(result.detections))
    d = result.detections.take(mixed)
    assert result.link_confidence is not None
    shuffled = dataclasses.replace(
        result,
        detections=d,
        groups=result.groups[mixed],
        link_confidence=result.link_confidence[mixed],
    )
    assert assert_written_alike(shuffled) == written(result, "polars")


@pytest.mark.parametrize("shared_position", [False, True])
def test_the_matrix_with_sensors_at_one_position_is_written_alike(shared_position):
    """Sensors at the same position: a target's detections by sensor (in road order, ties by
    name) are then not in the order `target_members` gives them (by position, then time), and
    the targets' confidences are the products in that order all the same."""
    rng = np.random.default_rng(5)
    names = ["E", "D", "C", "B", "A", "F"]
    n = 20 * len(names)
    k = np.arange(n) % len(names)
    sensors = np.array(names, dtype=object)[k]
    position = (np.array([0.0, 0, 0, 0, 0, 100]) if shared_position else 10.0 * np.arange(6))[k]
    d = Detections.from_columns(
        position, rng.uniform(10, 30, n), np.arange(n, dtype=float), list(sensors)
    )
    groups = np.where(np.arange(n) == 7, -1, np.arange(n) // len(names))
    confidence = np.where(k == 0, np.nan, rng.random(n))
    assert_written_alike(build_result(d, groups, "x", {}, link_confidence=confidence))


def test_no_detections_is_the_header():
    d = Detections.from_columns([], [], [])
    result = build_result(d, np.zeros(0, dtype=np.int64), "x", {})
    assert {written(result, way) for way in WAYS} == {"target\n"}


ids = st.text(alphabet=st.characters(min_codepoint=9, max_codepoint=126), min_size=1, max_size=5)
SENSORS = ("S'1", 'S"2', "S\\3", "=S4", "S,5")


@settings(max_examples=80, deadline=None)
@given(
    st.lists(st.tuples(ids, st.sampled_from(SENSORS)), min_size=1, max_size=40),
    st.integers(0, 2**32 - 1),
    st.booleans(),
)
def test_any_ids_groups_and_links_write_the_same_matrix_every_way(rows, seed, links):
    """Ids with quotes, commas, tabs, line breaks and formula starts; sensors named so; targets,
    unassigned detections, links and cells of several at random."""
    unique = list(dict.fromkeys(i for i, _ in rows))
    sensors = [s for _, s in rows][: len(unique)]
    n = len(unique)
    rng = np.random.default_rng(seed)
    position = np.array([100.0 * SENSORS.index(s) for s in sensors])
    d = Detections.from_columns(position, rng.uniform(10, 30, n), rng.uniform(0, 100, n), sensors)
    d = dataclasses.replace(d, detection_id=np.array(unique, dtype=object))
    groups = rng.integers(-1, 3, n)
    confidence = np.where(rng.random(n) < 0.3, np.nan, rng.random(n)) if links else None
    assert_written_alike(build_result(d, groups, "x", {}, link_confidence=confidence))


def test_ids_read_by_the_fast_reader_are_made_spreadsheet_safe():
    """A file's ids that start as formulas, unescaped (not a file roadlink wrote): the parser's
    column of them, which the matrix takes as it is, is made spreadsheet safe all the same."""
    original = grid(30, 20, 4, seen=0.9, ids=["=1+1", "+a", "-b", "@c", "f="])
    d = original.detections
    columns = (d.position, d.velocity, d.timestamp, d.sensor_id, d.detection_id)
    rows = "".join(",".join(map(str, row)) + "\n" for row in zip(*map(list, columns), strict=True))
    read = fast_read(f"position,velocity,timestamp,sensor_id,detection_id\n{rows}")
    assert read.parsed_texts("detection_id") is not None
    result = build_result(read, original.groups, "x", {}, link_confidence=original.link_confidence)
    matrix = assert_written_alike(result)
    assert "'=1+1" in matrix and "'@c" in matrix and ",f=," in matrix
