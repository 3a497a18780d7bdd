"""Columns of text made and joined by polars, for the result writers (`result_text`): a float
column as its numbers' text, and rows of text joined from columns and constant texts, without a
Python object per value.

polars writes a float as orjson does, and both as Python's `repr` except below 1e-4 in
magnitude (`1e-5` against `1e-05`) and where not finite: there `repr` is written in
(`tests/association/test_text_columns.py` checks both on hundreds of thousands of hard values).
"""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

if TYPE_CHECKING:
    import polars as pl

# polars is imported by each function, on the first result written: every process imports the
# core, and few write a result (a small job's worker need not pay polars' import).


def float_column(values: np.ndarray, spelling: str = "python") -> pl.Series:
    """The text of each float of `values`, as a polars String column: `repr`'s
    (`spelling="python"`), or orjson's (`"orjson"`, for finite values only)."""
    import polars as pl

    array = np.ascontiguousarray(values, dtype=np.float64)
    texts = pl.Series(array).cast(pl.String)
    if spelling == "python":
        odd = np.flatnonzero(~np.isfinite(array) | ((np.abs(array) < 1e-4) & (array != 0)))
        if odd.size:
            texts = texts.scatter(odd, [repr(v) for v in array[odd].tolist()])
    return texts


def text_column(values: Any) -> pl.Series:
    """Python strs or None (a list or an object array) as a polars String column."""
    import polars as pl

    return pl.Series(values, dtype=pl.String)


def has_any(texts: pl.Series, pattern: str) -> bool:
    """Whether a text of `texts` holds a match of the regular expression `pattern`."""
    return bool(texts.str.contains(pattern).any())


def prefixed(texts: pl.Series, starts: tuple[str, ...], prefix: str) -> pl.Series:
    """Each of `texts` (a polars String column, no nulls) with `prefix` before it where it
    starts with one of `starts`."""
    import polars as pl

    column = pl.lit(texts)
    starting = pl.any_horizontal([column.str.starts_with(start) for start in starts])
    return pl.select(pl.when(starting).then(pl.lit(prefix) + column).otherwise(column)).to_series()


def joined_rows(parts: list[Any], tail: str = "") -> str:
    """Each row's parts (columns of one length, as polars Series or lists of Python strs,
    expressions over them, or texts the same in every row) one after another, row after row,
    then `tail`, as one text."""
    return joined(joined_columns(parts), tail)


def joined_columns(parts: list[Any]) -> pl.Series:
    """Each row's parts (as `joined_rows` takes them) one after another: a text per row."""
    import polars as pl

    return pl.select(concatenated(parts)).to_series()


def joined(texts: pl.Series, tail: str = "") -> str:
    """The texts of `texts` one after another, then `tail`, as one text. The tail is joined
    as one more text: appended to the joined text, polars would copy it (twice the join's
    time for a matrix of 60 MB)."""

    return str(_joined(texts, tail).item())


def encoded_rows(parts: list[Any], tail: str = "") -> bytes:
    """`joined_rows(parts, tail)` as UTF-8, made from polars' text without a Python str
    between (a str, then its encoding, would copy the text twice more)."""
    import polars as pl

    return bytes(_joined(joined_columns(parts), tail).cast(pl.Binary).item())


def _joined(texts: pl.Series, tail: str) -> pl.Series:
    import polars as pl

    return pl.concat([texts, text_column([tail])]).str.join("")


def concatenated(parts: list[Any], separator: str = "") -> pl.Expr:
    """Each row's parts (as `joined_rows` takes them) one after another, `separator` between
    them, as an expression."""
    import polars as pl

    return pl.concat_str(_expressions(parts), separator=separator)


def where(mask: np.ndarray, then: list[Any], otherwise: str) -> pl.Expr:
    """Where `mask` holds, the text of the parts `then` (as `joined_rows` takes them) one
    after another; elsewhere the text `otherwise`."""
    import polars as pl

    condition = pl.lit(pl.Series(mask, dtype=pl.Boolean))
    return pl.when(condition).then(concatenated(then)).otherwise(pl.lit(otherwise))


def _expressions(parts: list[Any]) -> list[pl.Expr]:
    import polars as pl

    return [
        part
        if isinstance(part, pl.Expr)
        else pl.lit(text_column(part) if isinstance(part, list) else part)
        for part in parts
    ]


_Batch = TypeVar("_Batch")
_Made = TypeVar("_Made")


def made_in_order(make: Callable[[_Batch], _Made], batches: Iterable[_Batch]) -> Iterator[_Made]:
    """`make(batch)` of each batch, in order, made on as many threads as polars has: polars
    lets go of the GIL while it joins a batch's rows, so on two cores two batches are made at
    once (a 10^6-row result's JSON rows in 0.57 of the time, AMD EPYC). A batch is made at
    most that many batches ahead of the one the caller is writing, so that the text of only
    a few is held at once."""
    import polars as pl

    workers = max(1, pl.thread_pool_size())
    with ThreadPoolExecutor(max_workers=workers, thread_name_prefix="roadlink-text") as pool:
        pending: deque[Future[_Made]] = deque()
        for batch in batches:
            if len(pending) == workers:
                yield pending.popleft().result()
            pending.append(pool.submit(make, batch))
        while pending:
            yield pending.popleft().result()
