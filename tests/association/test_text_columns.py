"""polars' text of floats is Python's `repr` (or orjson's), and rows joined from columns and
constant texts are the rows' text, as the result writers need them byte for byte."""

import threading

import numpy as np
import orjson
import polars as pl
import pytest

from roadlink.association.text_columns import (
    concatenated,
    encoded_rows,
    float_column,
    has_any,
    joined,
    joined_rows,
    made_in_order,
    prefixed,
    text_column,
    where,
)


def hard_floats() -> np.ndarray:
    """Values whose shortest text is hard: every bit pattern at random, every magnitude, the
    bounds of the spellings (1e-4, 1e16) and of the doubles."""
    rng = np.random.default_rng(0)
    bits = rng.integers(0, 2**64 - 1, 200_000, dtype=np.uint64)
    edges = [0.0, -0.0, 1e-4, -1e-4, 9.999999999999999e-05, 1e16, -1e16, 9999999999999998.0]
    edges += [5e-324, 1.7976931348623157e308, 2.0**63, 1e15 + 0.5, 0.1 + 0.2, 1 / 3]
    values = np.concatenate(
        [
            edges,
            np.frombuffer(bits.tobytes(), dtype=np.float64),
            rng.standard_normal(100_000) * 10.0 ** rng.integers(-320, 308, 100_000),
            np.round(rng.uniform(0, 1000, 10_000), 1),
        ]
    )
    return values[np.isfinite(values)]


def test_float_column_is_repr_of_each_value():
    values = hard_floats()
    values = np.concatenate([values, [np.inf, -np.inf, np.nan, 1e-5, -1.5e-7]])
    assert float_column(values).to_list() == [repr(v) for v in values.tolist()]


def test_float_column_in_orjson_spelling_is_orjsons():
    values = hard_floats()
    expected = [orjson.dumps(v).decode() for v in values.tolist()]
    assert float_column(values, spelling="orjson").to_list() == expected


def test_joined_rows_interleave_columns_and_constant_texts():
    ids = text_column(["a", "bb", "c"])
    numbers = float_column(np.array([1.0, 1e-5, 2.5]))
    parts = ["<", ids, "=", numbers, pl.lit(">")]
    assert joined_rows(parts, "!") == "<a=1.0><bb=1e-05><c=2.5>!"


def test_encoded_rows_are_the_joined_rows_as_utf8():
    parts = ["<", text_column(["a", "\u00e9t\u00e9", "\U0001f697"]), ">", ["1", "2", "3"]]
    assert encoded_rows(parts, "\u00e9") == joined_rows(parts, "\u00e9").encode()
    assert encoded_rows(parts, "\u00e9").decode() == "<a>1<\u00e9t\u00e9>2<\U0001f697>3\u00e9"


def test_where_takes_the_text_where_the_mask_holds():
    chosen = where(np.array([True, False, True]), ["<", text_column(["x", "y", "z"])], "-")
    assert joined_rows([chosen]) == "<x-<z"


def test_has_any_finds_a_pattern_in_any_text():
    texts = text_column(["plain", None, 'quo"te'])
    assert has_any(texts, '"')
    assert not has_any(texts, r"\\")
    assert has_any(text_column(["tab\there"]), r"[^ -~]")
    assert not has_any(text_column(["printable ascii ~"]), r"[^ -~]")


def test_batches_are_made_in_order_and_at_most_a_pool_ahead_of_the_writer() -> None:
    workers = max(1, pl.thread_pool_size())
    started: list[int] = []
    lock = threading.Lock()

    def make(batch: int) -> str:
        with lock:
            started.append(batch)
        return f"<{batch}>"

    written = []
    for text in made_in_order(make, range(50)):
        written.append(text)
        # Batches beyond the one being written and the `workers` after it are not begun.
        assert max(started) < len(written) + workers
    assert written == [f"<{k}>" for k in range(50)]


def test_a_batch_that_fails_fails_the_text() -> None:
    def make(batch: int) -> str:
        if batch == 3:
            raise ValueError("batch 3")
        return str(batch)

    with pytest.raises(ValueError, match="batch 3"):
        list(made_in_order(make, range(10)))


def test_prefixed_puts_the_prefix_before_texts_with_a_start():
    texts = text_column(["=a", "ab", "b", "", "xa", "\ta"])
    assert prefixed(texts, ("=", "a", "\t"), "'").to_list() == ["'=a", "'ab", "b", "", "xa", "'\ta"]
    assert prefixed(texts, ("ab", "x"), "<").to_list() == ["=a", "<ab", "b", "", "<xa", "\ta"]


def test_joined_is_the_texts_then_the_tail():
    texts = text_column(["a", "", "bc"])
    assert joined(texts, "\n") == "abc\n"
    assert joined(texts) == "abc"
    assert texts.to_list() == ["a", "", "bc"]  # left as it was


def test_concatenated_puts_the_separator_between_parts():
    numbers = float_column(np.array([0.5, 1e-7]))
    parts = ["", text_column(["x", "y"]), numbers]
    assert pl.select(concatenated(parts, ",")).to_series().to_list() == [",x,0.5", ",y,1e-07"]
