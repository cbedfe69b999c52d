"""A table of equally long 1-D numpy columns that reads like a numpy structured array.

records.RunRecords holds its records and inputs this way: the decoder's columns are
used as they are (no interleaving copy into a structured array), and every reader
keeps the structured-array idiom it had: `t["field"]`, `t[mask]`, `t[indices]`,
`t[a:b]`, `len(t)`, `t.dtype.names`, `np.asarray(t)` (the structured array itself).

Indexing with a mask or indices returns a table whose columns are gathered on first
use, so `records[mask]["start_ns"]` costs one column, not all of them; a mask of one run
of rows, a slice (views of the columns: no gather at all); a mask of every row, the table
itself. Like numpy's
fancy indexing, the result behaves as a copy, as long as the parent's columns are not
modified in place while it lives (nothing here does: copy() before writing).

A column can also be derived: made from others on first use (`derive`), then held by the
table and every table indexed from it, so one a reader never asks for is never made (a
batch's generation repeated for each of its 10^7 records: 80 MB).
"""

from __future__ import annotations

from collections.abc import Callable, Iterator, Mapping
from typing import Any

import numpy as np


class ColumnTable:
    """Rows of named columns; `dtype` is the equivalent structured dtype."""

    __slots__ = ("_base", "_cache", "_derive", "_index", "_len", "dtype")

    def __init__(
        self, columns: Mapping[str, np.ndarray], dtype: np.dtype[Any], index: np.ndarray | None = None,
        derive: Mapping[str, Callable[[], np.ndarray]] | None = None,
    ) -> None:
        self.dtype = dtype
        self._base = dict(columns)
        self._derive = dict(derive or {})  # the columns not in _base yet: how to make each
        self._index = index  # rows of _base this table holds (None: all, in order)
        self._cache: dict[str, np.ndarray] = {} if index is not None else self._base
        if index is not None:
            self._len = len(index)
        else:
            self._len = len(next(iter(self._base.values()))) if self._base else 0

    @classmethod
    def of(cls, columns: Mapping[str, Any], dtype: np.dtype[Any],
           derive: Mapping[str, Callable[[], np.ndarray]] | None = None) -> ColumnTable:
        """From values per field of `dtype` (each cast to its field's type, not copied when it
        has it), the fields in `derive` made on first use (of their field's type)."""
        names = dtype.names or ()
        derive = derive or {}
        if set(columns) | set(derive) != set(names) or set(columns) & set(derive):
            raise ValueError(f"columns {sorted(columns)} and derived {sorted(derive)} do not match fields "
                             f"{list(names)}")
        out = {name: np.asarray(columns[name]).astype(dtype[name], copy=False) for name in names
               if name in columns}  # fmt: skip
        if len({len(v) for v in out.values()}) > 1:
            raise ValueError("columns of unequal lengths")
        return cls(out, dtype, derive=derive)

    @classmethod
    def empty(cls, dtype: np.dtype[Any], n: int = 0) -> ColumnTable:
        return cls({name: np.zeros(n, dtype=dtype[name]) for name in dtype.names or ()}, dtype)

    @classmethod
    def from_structured(cls, array: np.ndarray) -> ColumnTable:
        """A copy of a structured array, by columns."""
        return cls({name: np.ascontiguousarray(array[name]) for name in array.dtype.names or ()}, array.dtype)

    def __len__(self) -> int:
        return self._len

    @property
    def shape(self) -> tuple[int]:
        return (self._len,)

    @property
    def names(self) -> tuple[str, ...]:
        return self.dtype.names or ()

    def __getitem__(self, key: Any) -> Any:
        if isinstance(key, str):
            column = self._cache.get(key)
            if column is None:
                column = self._column(key) if self._index is None else self._column(key)[self._index]
                self._cache[key] = column
            return column
        if isinstance(key, (int, np.integer)):
            i = int(key) + (self._len if int(key) < 0 else 0)
            if not 0 <= i < self._len:
                raise IndexError(f"index {int(key)} is out of bounds for a table of {self._len} rows")
            return np.asarray(self[np.array([i])])[0]
        if isinstance(key, slice):
            if self._index is None:
                pending = {name: (lambda name=name: self._column(name)[key])
                           for name in self._derive if name not in self._base}  # fmt: skip
                return ColumnTable({k: v[key] for k, v in self._base.items()}, self.dtype, derive=pending)
            return self._view(self._index[key])
        key = np.asarray(key)
        if key.dtype == bool and key.shape == (self._len,) and key.all():
            return self  # every row (a process's cycles, none skipped): the columns it has already
        rows = self._rows(key)
        one_run = len(rows) and int(rows[-1]) - int(rows[0]) + 1 == len(rows)
        if self._index is None and key.dtype == bool and one_run:
            # One run of rows (a DPU's measured records: all but its warm-up): views, no gather.
            return self[int(rows[0]) : int(rows[-1]) + 1]
        return self._view(rows)

    def _column(self, name: str) -> np.ndarray:
        """A whole base column, made first if it is derived. Tables side by side in threads
        may both make it: each gets the first one kept."""
        column = self._base.get(name)
        if column is None:
            make = self._derive.get(name)
            if make is None:
                raise KeyError(name)
            column = self._base.setdefault(name, np.asarray(make()).astype(self.dtype[name], copy=False))
        return column

    def _view(self, index: np.ndarray) -> ColumnTable:
        """The rows `index` of the base columns, sharing them with this table (and so the
        derived ones, made once for all)."""
        view = ColumnTable.__new__(ColumnTable)
        view.dtype, view._base, view._derive, view._index = self.dtype, self._base, self._derive, index
        view._cache, view._len = {}, len(index)
        return view

    def _rows(self, key: np.ndarray) -> np.ndarray:
        """`key` (a mask or indices into this table) as indices into the base columns."""
        if key.dtype == bool:
            if key.shape != (self._len,):
                raise IndexError(f"boolean index of shape {key.shape} for a table of {self._len} rows")
            rows = np.flatnonzero(key)
        elif key.dtype.kind in "iu":
            if key.ndim != 1:
                raise IndexError("only 1-D index arrays")
            rows = key.astype(np.intp, copy=False)
            if len(rows) and (int(rows.max()) >= self._len or int(rows.min()) < -self._len):
                raise IndexError(f"index out of bounds for a table of {self._len} rows")
            if len(rows) and int(rows.min()) < 0:
                rows = np.where(rows < 0, rows + self._len, rows)
        elif key.size == 0:
            rows = np.zeros(0, dtype=np.intp)
        else:
            raise IndexError(f"cannot index a table with {key.dtype}")
        return rows if self._index is None else self._index[rows]

    def __setitem__(self, name: str, values: Any) -> None:
        """Write a column in place (values cast to its type), as a structured array would."""
        if not isinstance(name, str):
            raise TypeError("only whole columns can be assigned: t['field'] = values")
        self[name][...] = values

    def copy(self) -> ColumnTable:
        return ColumnTable({name: np.array(self[name]) for name in self.names}, self.dtype)

    def columns(self) -> dict[str, np.ndarray]:
        return {name: self[name] for name in self.names}

    def __array__(self, dtype: Any = None, copy: Any = None) -> np.ndarray:
        out = np.empty(self._len, dtype=self.dtype)
        for name in self.names:
            out[name] = self[name]
        return out if dtype is None else out.astype(dtype)

    def __iter__(self) -> Iterator[Any]:
        return iter(np.asarray(self))

    def __repr__(self) -> str:
        return f"ColumnTable({self._len} rows: {', '.join(self.names)})"
