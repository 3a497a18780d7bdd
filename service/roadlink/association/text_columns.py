"""Columns of text made and joined by polars, for the result writers (`result_text`): a float
column as its numbers' text, and rows of text joined from columns and constant texts, without a
Python object per value.

polars writes a float as orjson does, and both as Python's `repr` except below 1e-4 in
magnitude (`1e-5` against `1e-05`) and where not finite: there `repr` is written in
(`tests/association/test_text_columns.py` checks both on hundreds of thousands of hard values).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import polars as pl


def float_column(values: np.ndarray, spelling: str = "python") -> pl.Series:
    """The text of each float of `values`, as a polars String column: `repr`'s
    (`spelling="python"`), or orjson's (`"orjson"`, for finite values only)."""
    array = np.ascontiguousarray(values, dtype=np.float64)
    texts = pl.Series(array).cast(pl.String)
    if spelling == "python":
        odd = np.flatnonzero(~np.isfinite(array) | ((np.abs(array) < 1e-4) & (array != 0)))
        if odd.size:
            texts = texts.scatter(odd, [repr(v) for v in array[odd].tolist()])
    return texts


def text_column(values: Any) -> pl.Series:
    """Python strs or None (a list or an object array) as a polars String column."""
    return pl.Series(values, dtype=pl.String)


def has_any(texts: pl.Series, pattern: str) -> bool:
    """Whether a text of `texts` holds a match of the regular expression `pattern`."""
    return bool(texts.str.contains(pattern).any())


def joined_rows(parts: list[Any], tail: str = "", binary: bool = False) -> str | bytes:
    """Each row's parts (columns of one length, expressions over them, or texts the same in
    every row) one after another, row after row, then `tail`, as one text (UTF-8 bytes with
    `binary`: no decoded copy)."""
    exprs = [part if isinstance(part, pl.Expr) else pl.lit(part) for part in parts]
    joined = pl.concat_str(exprs).str.join("") + pl.lit(tail)
    if binary:
        return bytes(pl.select(joined.cast(pl.Binary)).item())
    return str(pl.select(joined).item())


def where(mask: np.ndarray, then: pl.Expr, otherwise: str) -> pl.Expr:
    """`then`'s text where `mask` holds, else the text `otherwise`."""
    condition = pl.lit(pl.Series(mask, dtype=pl.Boolean))
    return pl.when(condition).then(then).otherwise(pl.lit(otherwise))
