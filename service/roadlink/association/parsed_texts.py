"""A text column kept as the CSV parser made it until something reads it as Python strs.

A million detection ids are a million `str` objects: making them is a fifth of a 10^6-row
CSV read, and a result writer that joins its rows in polars (`text_columns`) then turns them
back into a polars column. The fast reader (`fast_csv`) therefore hands `Detections` its ids
and labels as the parser's columns (`ParsedTexts`); `Detections.detection_id` and `.target` are
the object arrays all the same, made on first read (`DeferredColumn`), and a writer or the
scoring that can take the parser's column asks for it (`Detections.parsed_texts`) and never
makes the strs. The sensor ids' strs (a few, shared by their rows) the read makes anyway, to
check each id's position: their column is kept beside them, for the writers.
"""

from __future__ import annotations

import threading
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, overload

from roadlink.association.columns import ObjectArray

if TYPE_CHECKING:
    import polars as pl


class ParsedTexts:
    """A polars String column (null where a cell is empty), and its object array (None there)
    once asked for, made by `make` (one str per row by default) or given made (`objects`)."""

    def __init__(
        self,
        series: pl.Series,
        make: Callable[[pl.Series], ObjectArray] | None = None,
        objects: ObjectArray | None = None,
    ) -> None:
        self.series = series
        self._make = make
        self._objects = objects  # made already, where the parser had it at hand
        self._lock = threading.Lock()

    @property
    def made(self) -> bool:
        """Whether the object array has been made."""
        return self._objects is not None

    def objects(self) -> ObjectArray:
        """The texts as an object array of `str`, made once (two threads asking at once make
        it once as well: the writers may read a result's columns from a pool)."""
        with self._lock:
            if self._objects is None:
                if self._make is not None:
                    self._objects = self._make(self.series)
                else:
                    self._objects = self.series.to_numpy().astype(object, copy=False)
            return self._objects

    def __getstate__(self) -> dict[str, Any]:
        # `make` pickles by name: a module's function, never a lambda.
        return {"series": self.series, "make": self._make, "objects": self._objects}

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.series = state["series"]
        self._make = state["make"]
        self._objects = state["objects"]
        self._lock = threading.Lock()


class DeferredColumn:
    """A column of the frozen dataclass `Detections` that may be given as `ParsedTexts`: it
    reads as the object array, made on first read; `parsed` gives the parser's column.

    A descriptor-typed field: the dataclass's `__init__` sets it through `__set__`, and, as
    `__get__` on the class raises AttributeError, the field has no default."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name
        self.slot = f"_{name}_column"

    @overload
    def __get__(self, instance: None, owner: type) -> DeferredColumn: ...

    @overload
    def __get__(self, instance: object, owner: type) -> ObjectArray: ...

    def __get__(self, instance: object | None, owner: type) -> ObjectArray | DeferredColumn:
        if instance is None:
            raise AttributeError(self.name)  # no default (see the class docstring)
        value = instance.__dict__[self.slot]
        return value.objects() if isinstance(value, ParsedTexts) else value

    def __set__(self, instance: object, value: ObjectArray | ParsedTexts) -> None:
        instance.__dict__[self.slot] = value

    def stored(self, instance: object) -> ObjectArray | ParsedTexts:
        """The column as it is held: a copy of the detections built from it stays deferred."""
        value: ObjectArray | ParsedTexts = instance.__dict__[self.slot]
        return value

    def parsed(self, instance: object) -> ParsedTexts | None:
        """The column as the parser gave it, when it did."""
        value = self.stored(instance)
        return value if isinstance(value, ParsedTexts) else None


def generated_ids(n: int) -> ParsedTexts:
    """The ids d1, d2, ... dn that a file without a `detection_id` column gets, made by polars."""
    import polars as pl

    numbers = pl.int_range(1, n + 1, eager=True).cast(pl.String)
    return ParsedTexts(("d" + numbers).rename("detection_id"))
