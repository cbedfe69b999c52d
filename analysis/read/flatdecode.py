"""Bulk decoding of "flat" LCM messages (scalars and 1-D primitive arrays) into numpy.

A message with strings, or with arrays of fixed-size structs, can have its scalars decoded
so too (FlatLayout.of(..., skipping=True)): those fields are passed over, their values not read.

The wire contract is lcmtypes/ only: the layout here is derived at import time from
the lcm-gen Python class (its __slots__, __typenames__, __dimensions__ and packed
fingerprint), never written by hand. Every message of a kind is decoded at
once, straight from the log's memory map: the cost is a few numpy operations per
field, not per message, and never one Python object per value.
"""

from __future__ import annotations

import importlib
import itertools
import struct
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from .parallel import WORKERS, map_threads

# LCM type -> (numpy dtype, struct code). Struct codes are explicit because numpy's
# dtype.char for int64 is "l", which struct's standard sizes read as 4 bytes.
_PRIMITIVES = {
    "int8_t": ("i1", "b"),
    "byte": ("u1", "B"),
    "boolean": ("i1", "b"),
    "int16_t": (">i2", "h"),
    "int32_t": (">i4", "i"),
    "int64_t": (">i8", "q"),
    "float": (">f4", "f"),
    "double": (">f8", "d"),
}


@dataclass(frozen=True)
class _Scalars:
    names: tuple[str, ...]
    fmt: struct.Struct


@dataclass(frozen=True)
class _Arrays:
    names: tuple[str, ...]  # consecutive arrays of one dtype and one length field
    dtype: np.dtype[Any]
    length: str

    @property
    def size(self) -> int:
        """Bytes per count of `length`: an element of each array."""
        return self.dtype.itemsize * len(self.names)


@dataclass(frozen=True)
class _Skipped:
    """A field passed over: a string (its byte count, a uint32, in front of it: `length`
    None), or `length` structs of `size` bytes each."""

    name: str
    length: str | None
    size: int


_Step = _Scalars | _Arrays | _Skipped


@dataclass(frozen=True)
class FlatLayout:
    """The decoding plan of one lcm-gen class: runs of scalars, runs of arrays, and the fields
    passed over (skipping)."""

    name: str
    fingerprint: bytes
    steps: tuple[_Step, ...]
    arrays: tuple[str, ...]

    @property
    def head(self) -> tuple[tuple[str, ...], struct.Struct]:
        """The scalars in front of the first array (readable without decoding arrays)."""
        first = self.steps[0]
        if not isinstance(first, _Scalars):
            raise TypeError(f"{self.name} does not start with a scalar")
        return first.names, first.fmt

    @classmethod
    def of(cls, msg_class: type, skipping: bool = False) -> FlatLayout:
        """`skipping`: strings and arrays of fixed-size structs are passed over (_Skipped),
        not refused."""
        steps: list[_Step] = []
        for slot, typename, dims in zip(
            msg_class.__slots__, msg_class.__typenames__, msg_class.__dimensions__, strict=True
        ):
            if typename not in _PRIMITIVES:
                skipped = _skipped(slot, typename, dims) if skipping else None
                if skipped is None:
                    raise TypeError(f"{msg_class.__name__}.{slot}: {typename} is not a flat field")
                steps.append(skipped)
                continue
            dtype_name, code = _PRIMITIVES[typename]
            dtype = np.dtype(dtype_name)
            if dims is None:
                last = steps[-1] if steps else None
                if isinstance(last, _Scalars):
                    steps[-1] = _Scalars((*last.names, slot), struct.Struct(last.fmt.format + code))
                else:
                    steps.append(_Scalars((slot,), struct.Struct(">" + code)))
                continue
            if len(dims) != 1 or not isinstance(dims[0], str):
                raise TypeError(f"{msg_class.__name__}.{slot}: only 1-D arrays with a length field")
            last = steps[-1] if steps else None
            if isinstance(last, _Arrays) and last.dtype == dtype and last.length == dims[0]:
                steps[-1] = _Arrays((*last.names, slot), dtype, dims[0])
            else:
                steps.append(_Arrays((slot,), dtype, dims[0]))
        arrays = tuple(n for s in steps if isinstance(s, _Arrays) for n in s.names)
        return cls(msg_class.__name__, msg_class._get_packed_fingerprint(), tuple(steps), arrays)


def _skipped(slot: str, typename: str, dims: list[Any] | None) -> _Skipped | None:
    """How to pass over field `slot`, if it can be passed over without decoding it."""
    if typename == "string" and dims is None:
        return _Skipped(slot, None, 0)
    if dims is None or len(dims) != 1 or not isinstance(dims[0], str):
        return None
    package, _, name = typename.rpartition(".")  # lcm-gen names a struct package.name
    nested = getattr(importlib.import_module(package), name, None) if package else None
    if nested is None or any(t not in _PRIMITIVES or d is not None
                             for t, d in zip(nested.__typenames__, nested.__dimensions__, strict=True)):
        return None
    return _Skipped(slot, dims[0], sum(np.dtype(_PRIMITIVES[t][0]).itemsize for t in nested.__typenames__))


@dataclass
class Decoded:
    """Many messages of one flat type, decoded together."""

    ok: np.ndarray  # bool per message: fingerprint, lengths and size all valid
    scalars: dict[str, np.ndarray]  # int64/float64 per message (0 where not ok)
    counts: dict[str, np.ndarray]  # length field -> elements per *ok* message
    columns: dict[str, np.ndarray]  # array field -> native-endian values of the ok messages
    passed: dict[str, tuple[np.ndarray, np.ndarray]]  # field passed over -> the bytes it spans
    # per message, [start, end) of the log (a string: its byte count too); 0 where not ok


def decode_many(
    layout: FlatLayout, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
    release: Callable[[int, int], None] | None = None,
) -> Decoded:
    """Decode the messages at buf[starts[i] : starts[i] + lengths[i]] in bulk.

    Every step is one numpy operation over many messages, never a Python loop per
    message: positions follow from the length fields, and each array element is read
    with one fancy index. A message whose fingerprint, lengths or size do not fit is
    marked not ok (malformed) and contributes nothing. The messages are read CHUNK_BYTES
    of the file at a time, their heads first, then their arrays, and `release(start, end)`
    is told after each chunk that buf[start:end] is not needed for now (Log.release gives
    a map's pages back: read again, they cost a page fault each, so a page is faulted in
    about three times over a decode: the heads, the arrays' places, their values).
    """
    starts = np.asarray(starts, dtype=np.int64)
    end = starts + np.asarray(lengths, dtype=np.int64)
    ok, scalars, placed, passed = _place_chunks(layout.steps, layout, buf, starts, end, release)
    arrays = [step for step in layout.steps if isinstance(step, _Arrays)]
    good = np.flatnonzero(ok)
    counts = {step.length: scalars[step.length][good].astype(np.int64) for step in arrays}
    plan = [
        _Column(name, at[good] + j * counts[step.length] * step.dtype.itemsize, step.length, step.dtype)
        for step, at in zip(arrays, placed, strict=True)
        for j, name in enumerate(step.names)  # array j of a run starts j * n * size bytes in
    ]
    # Every column is a view into one arena: one big allocation is mapped with huge
    # pages, where one allocation per column costs a page fault every 4 kB (measured:
    # more than the copying itself).
    sizes = [int(counts[c.length].sum()) * c.dtype.itemsize for c in plan]
    arena = np.empty(sum(sizes), dtype=np.uint8)
    outs = [out.view(c.dtype) for c, out in zip(plan, np.split(arena, np.cumsum(sizes)[:-1]), strict=True)] \
        if plan else []  # fmt: skip
    firsts = {length: np.cumsum(n) - n for length, n in counts.items()}
    for lo, hi in file_chunks(starts[good], end[good]):
        _fill(plan, outs, buf, counts, firsts, lo, hi)
        if release is not None:
            release(int(starts[good[lo]]), int(end[good[hi - 1]]))
    columns = {c.name: out.view(c.dtype.newbyteorder("=")) for c, out in zip(plan, outs, strict=True)}
    passed = {name: (np.where(ok, lo, 0), np.where(ok, hi, 0)) for name, (lo, hi) in passed.items()}
    return Decoded(ok=ok, scalars=scalars, counts=counts, columns=columns, passed=passed)


class _Placed(NamedTuple):
    """Where the values of some messages lie."""

    ok: np.ndarray  # per message, as Decoded.ok
    scalars: dict[str, np.ndarray]  # per message, as Decoded.scalars
    arrays: list[np.ndarray]  # per run of arrays (layout order), per message: the byte it starts at
    passed: dict[str, tuple[np.ndarray, np.ndarray]]  # per field passed over, as Decoded.passed

    @classmethod
    def concat(cls, parts: list[_Placed]) -> _Placed:
        """Consecutive messages' parts as one."""
        ok = np.concatenate([p.ok for p in parts])
        scalars = {name: np.concatenate([p.scalars[name] for p in parts]) for name in parts[0].scalars}
        arrays = [np.concatenate(runs) for runs in zip(*(p.arrays for p in parts), strict=True)]
        passed = {name: (np.concatenate([p.passed[name][0] for p in parts]),
                         np.concatenate([p.passed[name][1] for p in parts]))
                  for name in parts[0].passed}  # fmt: skip
        return cls(ok, scalars, arrays, passed)


def _place_chunks(
    steps: tuple[_Step, ...], layout: FlatLayout, buf: np.ndarray, starts: np.ndarray,
    end: np.ndarray, release: Callable[[int, int], None] | None,
) -> _Placed:
    """_place, a chunk of the file at a time: the messages' heads lie on most pages of a
    timing log."""
    return _Placed.concat([_place(steps, layout, buf, starts[lo:hi], end[lo:hi], release)
                           for lo, hi in file_chunks(starts, end) or [(0, 0)]])  # fmt: skip


def _place(
    steps: tuple[_Step, ...], layout: FlatLayout, buf: np.ndarray, starts: np.ndarray,
    end: np.ndarray, release: Callable[[int, int], None] | None,
) -> _Placed:
    """Where the values of the messages from `starts` to `end` lie, read as far as `steps`
    (the first of layout.steps, or all of them) go."""
    fp = int.from_bytes(layout.fingerprint, "big")
    ok = end - starts >= 8
    ok &= _gather(buf, np.where(ok, starts, 0), np.dtype(">u8")) == fp
    pos = starts + 8
    scalars: dict[str, np.ndarray] = {}
    placed: list[np.ndarray] = []
    passed: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for step in steps:
        if isinstance(step, _Scalars):
            ok &= pos + step.fmt.size <= end
            values = _gather(buf, np.where(ok, pos, 0), _record_dtype(step))
            for name in step.names:
                scalars[name] = np.where(ok, values[name], 0)
            pos = pos + step.fmt.size
            continue
        first = pos
        if step.length is None:  # a string passed over: its byte count, then its bytes
            ok &= pos + 4 <= end
            pos = pos + 4 + _gather(buf, np.where(ok, pos, 0), np.dtype(">u4")).astype(np.int64)
        else:  # `length` elements of `size` bytes: arrays, or structs passed over
            n = scalars[step.length]
            ok &= n >= 0
            # int64 before multiplying: an int32 length of 2**30 times 8 bytes wrapped negative,
            # passed the size check and asked for a 39 GiB column (a flipped bit, Hypothesis)
            pos = pos + np.where(ok, n, 0).astype(np.int64) * step.size
        ok &= pos <= end
        if isinstance(step, _Arrays):
            placed.append(first)
        else:
            passed[step.name] = (first, pos)
    if release is not None and len(starts):
        release(int(starts[0]), int(end.max()))
    return _Placed(ok, scalars, placed, passed)


@dataclass(frozen=True)
class _Column:
    name: str
    at: np.ndarray  # per message: the byte where its values start
    length: str  # the length field that counts them
    dtype: np.dtype[Any]  # on the wire


CHUNK_BYTES = 256 << 20  # of the file read at once: what a decode holds of a mapped log


def file_chunks(starts: np.ndarray, ends: np.ndarray) -> list[tuple[int, int]]:
    """Consecutive runs [lo, hi) of the messages, each spanning about CHUNK_BYTES of the file."""
    if len(starts) == 0:
        return []
    cuts = np.searchsorted(starts, np.arange(int(starts[0]), int(ends.max()), CHUNK_BYTES)[1:])
    bounds = np.unique(np.r_[0, cuts, len(starts)])
    return list(zip(bounds[:-1].tolist(), bounds[1:].tolist(), strict=True))


def _fill(
    plan: list[_Column], outs: list[np.ndarray], buf: np.ndarray, counts: dict[str, np.ndarray],
    firsts: dict[str, np.ndarray], lo: int, hi: int,
) -> None:
    """The values of messages [lo, hi) into their places in `outs`, the columns side by side
    (parallel.py), each worker with its own scratch for padded rows."""
    n = {length: c[lo:hi] for length, c in counts.items()}
    paddings = {length: _Padding.of(m) for length, m in n.items() if _unequal(m) and _padded(m)}
    scratch_bytes = max([paddings[c.length].elements * c.dtype.itemsize for c in plan if c.length in paddings]
                        + [0])  # fmt: skip
    first = {length: int(f[lo]) for length, f in firsts.items()}
    total = {length: int(m.sum()) for length, m in n.items()}
    work = [(c, out[first[c.length] : first[c.length] + total[c.length]])
            for c, out in zip(plan, outs, strict=True)]  # fmt: skip
    workers = min(WORKERS, len(work))

    def fill(worker: int) -> None:
        scratch = np.empty(scratch_bytes, dtype=np.uint8)
        for c, out in itertools.islice(work, worker, None, workers):
            _concat_into(out, buf, c.at[lo:hi], n[c.length], scratch, paddings.get(c.length))

    map_threads(fill, range(workers), sum(out.nbytes for _, out in work))


def _unequal(n: np.ndarray) -> bool:
    return len(n) > 0 and int(n.min()) != int(n.max())


def _padded(n: np.ndarray) -> bool:
    """Read as padded rows (else by groups of one length): when padding every row to
    the longest would cost at most as much as the values themselves."""
    return len(n) * int(n.max(initial=0)) <= 2 * int(n.sum()) + 4096


@dataclass(frozen=True)
class _Padding:
    """Messages of unequal lengths as padded rows, in a few classes of similar length
    (by quantile), each padded to its own longest: less padding to copy than one width
    for all. `kept` = where each real value is, in message order, among all the rows."""

    classes: tuple[tuple[np.ndarray, int, int], ...]  # (members, width, first element)
    kept: np.ndarray
    elements: int  # of all the rows

    CLASSES = 4

    @classmethod
    def of(cls, n: np.ndarray) -> _Padding:
        order = np.argsort(n, kind="stable")
        bounds = np.linspace(0, len(n), cls.CLASSES + 1).astype(np.int64).tolist()
        row_start = np.zeros(len(n), dtype=np.int64)
        classes = []
        elements = 0
        for a, b in itertools.pairwise(bounds):
            members = np.sort(order[a:b])  # in file order: the reads go forward
            width = int(n[members].max(initial=0))
            if width == 0:
                continue
            row_start[members] = elements + np.arange(len(members)) * width
            classes.append((members, width, elements))
            elements += len(members) * width
        first = np.cumsum(n) - n
        kept = np.repeat(row_start - first, n) + np.arange(int(n.sum()))
        return cls(tuple(classes), kept, elements)


def _concat_into(
    out: np.ndarray, buf: np.ndarray, at: np.ndarray, n: np.ndarray, scratch: np.ndarray,
    padding: _Padding | None,
) -> None:
    """Fill `out` (of the wire dtype) with the n[i] values starting at byte at[i], for
    every i, concatenated, then swap it to native byte order in place.

    One opaque row per message read in one fancy index; when the lengths differ, rows
    are padded (see _Padding) and the real values taken from them in order."""
    dtype = out.dtype
    if len(out) == 0:
        return
    size = dtype.itemsize
    if padding is None and _unequal(n):
        _concat_groups(out, buf, at, n)
    elif padding is None:
        width = int(n.max()) * size
        _rows_into(out.view(np.uint8).view(np.dtype((np.void, width))), buf, at, width)
    else:
        for members, width, first in padding.classes:
            rows = scratch[first * size : (first + len(members) * width) * size]
            _rows_into(rows.view(np.dtype((np.void, width * size))), buf, at[members], width * size)
        # mode="clip" writes `out` directly (np.compress and mode="raise" buffer it: 4x slower)
        np.take(scratch[: padding.elements * size].view(dtype), padding.kept, out=out, mode="clip")
    if dtype.byteorder == ">":
        out.byteswap(inplace=True)


_GATHER_BYTES = 1 << 20


def _rows_into(dest: np.ndarray, buf: np.ndarray, at: np.ndarray, width: int) -> None:
    """dest[i] = the `width` bytes from at[i]. A row may run past the end of the
    buffer (padding after a short last message): those few come from a zero-padded
    copy of the tail."""
    items = _items(buf, width)
    inside = at <= len(buf) - width
    if bool(inside.all()):
        # A few rows at a time: a fancy index gathers into a new array before the copy into
        # `dest`, which, the size of the column, was fresh memory to back (np.take into `dest`
        # would copy the whole overlapping view first).
        step = max(1, _GATHER_BYTES // width)
        for lo in range(0, len(at), step):
            dest[lo : lo + step] = items[at[lo : lo + step]]
        return
    if inside.any():
        dest[inside] = items[at[inside]]
    low = int(at[~inside].min())
    tail = np.zeros(len(buf) - low + width, dtype=np.uint8)
    tail[: len(buf) - low] = buf[low:]
    dest[~inside] = _items(tail, width)[at[~inside] - low]


def _concat_groups(out: np.ndarray, buf: np.ndarray, at: np.ndarray, n: np.ndarray) -> None:
    """_concat_into by groups of messages of one length (very unequal lengths)."""
    size = out.dtype.itemsize
    first = np.cumsum(n) - n
    values, inverse = np.unique(n, return_inverse=True)
    for g, count in enumerate(values.tolist()):
        if count == 0:
            continue
        members = np.flatnonzero(inverse == g)
        rows = np.empty(len(members), dtype=np.dtype((np.void, count * size)))
        _rows_into(rows, buf, at[members], count * size)
        out[(first[members][:, None] + np.arange(count)).ravel()] = rows.view(out.dtype)


def _items(buf: np.ndarray, width: int) -> np.ndarray:
    """Item i = the `width` bytes starting at byte i (a stride-1 view, no copy). Opaque
    items index fastest: no per-field transfer."""
    opaque = np.dtype((np.void, width))
    return np.ndarray(shape=(max(0, len(buf) - width + 1),), dtype=opaque, buffer=buf, strides=(1,))


def decode_heads(
    layout: FlatLayout, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
    release: Callable[[int, int], None] | None = None,
) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Only the scalars in front of the first array (fingerprint checked): enough to
    choose messages (a run, a DPU) before decoding their arrays. `release`: as decode_many's
    (called with what it no longer needs, not a promise never to read it again)."""
    if not isinstance(layout.steps[0], _Scalars):
        raise TypeError(f"{layout.name} does not start with a scalar")
    starts = np.asarray(starts, dtype=np.int64)
    ok, scalars, _, _ = _place_chunks(layout.steps[:1], layout, buf, starts,
                                   starts + np.asarray(lengths, dtype=np.int64), release)
    return ok, scalars


def _record_dtype(step: _Scalars) -> np.dtype[Any]:
    codes = {"b": "i1", "B": "u1", "h": ">i2", "i": ">i4", "q": ">i8", "f": ">f4", "d": ">f8"}
    return np.dtype([(name, codes[c]) for name, c in zip(step.names, step.fmt.format[1:], strict=True)])


def _gather(buf: np.ndarray, at: np.ndarray, dtype: np.dtype[Any]) -> np.ndarray:
    """The (unaligned, big-endian) value of `dtype` starting at each byte offset in `at`.

    A stride-1 view of opaque items makes "the bytes starting at i" element i, so one
    fancy index reads every value; viewing the result as `dtype` then costs nothing.
    """
    size = dtype.itemsize
    if len(at) == 0 or len(buf) < size:
        return np.zeros(len(at), dtype=dtype).astype(dtype.newbyteorder("="))
    opaque = np.dtype((np.void, size))
    items = np.ndarray(shape=(len(buf) - size + 1,), dtype=opaque, buffer=buf, strides=(1,))
    out = items[at].view(dtype)
    if dtype.names is None:
        return out.astype(dtype.newbyteorder("="))
    return out
