"""The fast writers of a result write exactly what the plain ones wrote: `json.dumps(document,
indent=2)` for the CLI's --json, `orjson.dumps(document)` for the service's stored result (the
matrix: `test_matrix_text`)."""

import dataclasses
import io
import json

import numpy as np
import orjson
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from roadlink.association import associate, result_text
from roadlink.association.csvio import write_detections_csv
from roadlink.association.detections import Detections
from roadlink.association.result import build_result
from roadlink.association.result_text import (
    json_detection_texts,
    result_json_compact,
    result_json_text,
)
from roadlink.simulation import preset, simulate
from tests.helpers import fast_read


@pytest.fixture(autouse=True, scope="module", params=["polars", "lists"])
def rows_made_by(request):
    """Every test twice: the rows' text made by polars (as from `_POLARS_ROWS` detections),
    and by Python lists (as below it): the same bytes either way."""
    before = result_text._POLARS_ROWS
    result_text._POLARS_ROWS = 0 if request.param == "polars" else 10**9
    yield request.param
    result_text._POLARS_ROWS = before


def results():
    featured = preset("medium", lanes=3, vehicle_lengths=True, vehicle_classes=True)
    faulty = preset("small", miss_probability=0.1, false_alarm_rate=0.1, duplicate_probability=0.05)
    out = [
        associate(simulate(preset("large"), seed=2).detections, "assignment", {}),
        associate(simulate(faulty, seed=2).detections, "assignment", {}),
        associate(simulate(featured, seed=2).detections, "assignment", {}),
        associate(simulate(featured, seed=2).detections, "kmeans", {}),  # cells of several
    ]
    d = simulate(preset("large"), seed=3).detections
    n = len(d)
    tiny = dataclasses.replace(d, velocity=d.velocity * 1e-7, timestamp=d.timestamp * 1e-9)
    groups = np.where(np.arange(n) % 3 == 0, -1, np.arange(n) % 7)
    small_links = np.where(np.arange(n) % 4 == 0, np.nan, 1e-5)
    out += [
        build_result(tiny, np.arange(n) % 7, "x", {"p": 1e-6}, link_confidence=np.full(n, 1e-3)),
        build_result(d, groups, "x", {"p": [1e-6, 2]}, link_confidence=small_links),
        build_result(d, groups, "x", {"q": "\u00e9"}, link_confidence=small_links),
    ]
    # Read by the fast CSV reader: the ids are polars' column, given to the writers as it is.
    read = fast_read(write_detections_csv(simulate(faulty, seed=4).detections))
    rows = zip(d.position.tolist(), d.velocity.tolist(), d.timestamp.tolist(), strict=True)
    numbers = "position,velocity,timestamp\n" + "".join(f"{p!r},{v!r},{t!r}\n" for p, v, t in rows)
    generated = fast_read(numbers)  # ids d1, d2, ... made by polars
    assert read.parsed_texts("detection_id") is not None
    assert generated.parsed_texts("detection_id") is not None
    out += [associate(read, "assignment", {}), build_result(generated, groups, "x", {})]
    return out


@pytest.mark.parametrize("result", results())
def test_the_cli_json_is_json_dumps_byte_for_byte(result):
    assert result_json_text(result) == json.dumps(result.to_dict(), indent=2) + "\n"


@pytest.mark.parametrize("result", results())
def test_the_cli_json_from_row_texts_made_beforehand_is_json_dumps_byte_for_byte(result):
    """The CLI makes the rows' text that needs no grouping while it associates: the same
    bytes; texts made of other detections, or for the compact text, are not taken."""
    expected = json.dumps(result.to_dict(), indent=2) + "\n"
    assert result_json_text(result, json_detection_texts(result.detections)) == expected
    other = dataclasses.replace(result.detections)
    assert result_json_text(result, json_detection_texts(other)) == expected
    compact = result_text.DetectionTexts(result.detections, result_text._COMPACT).prepared()
    assert result_json_text(result, compact) == expected


@pytest.mark.parametrize("result", results())
def test_metrics_given_later_are_written_after_the_rows_as_json_dumps_wrote_them(result):
    """An unscored result written with its metrics to come (the CLI scores it meanwhile):
    the same bytes, and the metrics asked for only once every row is written (or before
    anything, where the plain encoder writes the document: text orjson spells otherwise)."""
    expected = json.dumps(result.to_dict(), indent=2) + "\n"
    unscored = dataclasses.replace(result, metrics=None)
    out = io.BytesIO()
    written_when_asked = []

    def metrics():
        written_when_asked.append(out.getvalue().decode())
        return result.metrics

    result_text.write_result_json(unscored, out, metrics=metrics)
    assert out.getvalue().decode() == expected
    (before,) = written_when_asked
    assert expected.startswith(before)
    assert before == "" or before.count('"detection_id"') == len(result.detections)
    assert before or not json.dumps(result.params, ensure_ascii=False).isascii()


def test_the_rows_made_beforehand_are_gathered_not_made_again(monkeypatch, rows_made_by):
    """With texts made beforehand, the writer makes the rows' columns again only for the
    unassigned detections (rows indented otherwise); by Python lists, nothing is made ahead."""
    result = results()[1]  # faulty traffic: unassigned detections too
    texts = json_detection_texts(result.detections)
    made = []
    making = result_text.DetectionTexts._columns
    monkeypatch.setattr(
        result_text.DetectionTexts,
        "_columns",
        lambda self, index, inner: made.append(inner) or making(self, index, inner),
    )
    result_json_text(result, texts)
    inner = result_text.TARGET_ROWS_INDENT + 2
    assert (result.groups < 0).any()
    assert made == ([4 + 2] if rows_made_by == "polars" else [inner, 4 + 2])


@pytest.mark.parametrize("result", results())
def test_the_stored_json_is_orjson_of_the_row_objects_byte_for_byte(result):
    assert result_json_compact(result) == orjson.dumps(result.to_dict()).decode()


def test_the_stored_json_of_text_orjson_writes_otherwise_is_orjson_of_the_rows():
    """Ids that are not printable ASCII: orjson writes them raw, control characters escaped."""
    d = simulate(preset("small"), seed=1).detections
    ids = [f"\u00e9{i}" if i % 2 else f"tab\t{i}" for i in range(len(d))]
    d = dataclasses.replace(d, detection_id=np.array(ids, dtype=object))
    result = build_result(d, np.arange(len(d)) % 5 - 1, "x", {})
    assert result_json_compact(result) == orjson.dumps(result.to_dict()).decode()


def test_float_texts_are_repr():
    values = np.array([0.0, -0.0, 1e-5, 1.5e-7, 0.1, 1 / 3, 1e16, 123.0, np.inf, np.nan])
    assert result_text.float_texts(values) == [repr(v) for v in values.tolist()]


def test_float_texts_in_orjson_spelling_are_orjsons_of_python_floats():
    values = np.array([0.0, -0.0, 1e-5, -1.5e-7, 5e-324, 0.1, 1 / 3, 1e16, 123.0, 1.7e308])
    expected = [orjson.dumps(v).decode() for v in values.tolist()]
    assert result_text.float_texts(values, spelling="orjson") == expected
    assert expected[2] != repr(1e-5)  # the two spellings differ there


def test_float_texts_take_a_prefix_and_a_suffix():
    values = np.array([0.5, 1e-5, np.nan, -2.0, 1e16])
    assert result_text.float_texts(values, "<", ">") == [f"<{v!r}>" for v in values.tolist()]
    assert result_text.float_texts(np.array([]), "<", ">") == []


def test_the_cli_json_is_json_dumps_across_batches_of_rows(monkeypatch):
    """The rows' text is written a batch of targets at a time: batches of one row each."""
    monkeypatch.setattr(result_text, "_BATCH_ROWS", 1)
    for result in results()[:3]:
        assert result_json_text(result) == json.dumps(result.to_dict(), indent=2) + "\n"
        assert result_json_compact(result) == orjson.dumps(result.to_dict()).decode()


ids = st.text(alphabet=st.characters(min_codepoint=32, max_codepoint=126), min_size=1, max_size=5)


@settings(max_examples=60, deadline=None)
@given(
    st.lists(
        st.tuples(ids, st.sampled_from(["S'1", 'S"2', "S\\3", "=S4"])), min_size=1, max_size=30
    ),
    st.integers(0, 2**32 - 1),
    st.booleans(),
)
def test_any_ids_groups_and_links_write_as_the_plain_writers_do(rows, seed, links):
    """Ids with quotes, backslashes, commas and formula starts; targets, unassigned detections
    and links at random: every writer gives the plain writers' bytes."""
    # Distinct as the reader keeps them: stripped (" 0" is "0"), a blank one generated.
    unique = list(dict.fromkeys(i.strip() or "blank" for i, _ in rows))
    sensors = [s for _, s in rows][: len(unique)]
    n = len(unique)
    rng = np.random.default_rng(seed)
    position = np.array([100.0 * ("S'1", 'S"2', "S\\3", "=S4").index(s) for s in sensors])
    d = Detections.from_columns(
        position, rng.uniform(10, 30, n), rng.uniform(0, 100, n), sensors, unique
    )
    groups = rng.integers(-1, 3, n)
    confidence = np.where(rng.random(n) < 0.3, np.nan, rng.random(n)) if links else None
    result = build_result(d, groups, "x", {}, link_confidence=confidence)
    assert result_json_text(result) == json.dumps(result.to_dict(), indent=2) + "\n"
    assert result_json_text(result, json_detection_texts(d)) == result_json_text(result)
    assert result_json_compact(result) == orjson.dumps(result.to_dict()).decode()


def test_plain_results_are_written_from_the_columns_not_by_the_plain_encoders(monkeypatch):
    """The fast writers write what they can (ids of printable ASCII, finite numbers, a float
    below 1e-4 among them) themselves: the plain encoders are never called for it."""

    def refused(*args, **kwargs):
        raise AssertionError("the plain encoder was called")

    for result in results()[:5]:
        expected = (json.dumps(result.to_dict(), indent=2) + "\n", result_json_compact(result))
        with monkeypatch.context() as patch:
            patch.setattr(result_text.json, "dumps", refused)
            patch.setattr(type(result), "to_dict", refused)
            assert (result_json_text(result), result_json_compact(result)) == expected
