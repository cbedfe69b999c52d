"""Bulk decoding of "flat" LCM messages (scalars and 1-D primitive arrays) into numpy.

The wire contract is lcmtypes/ only: the layout here is derived at import time from
the lcm-gen Python class (its __slots__, __typenames__, __dimensions__ and packed
fingerprint), never written by hand. Arrays stay big-endian views of the log's
memory map until they are concatenated, so one batch costs a handful of numpy calls
instead of one Python object per value.
"""

from __future__ import annotations

import struct
from dataclasses import dataclass
from typing import Any

import numpy as np

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


class MalformedMessage(ValueError):
    """A message whose bytes do not match its type (fingerprint, lengths, size)."""


@dataclass(frozen=True)
class _Scalars:
    names: tuple[str, ...]
    fmt: struct.Struct


@dataclass(frozen=True)
class _Arrays:
    names: tuple[str, ...]  # consecutive arrays of one dtype and one length field
    dtype: np.dtype[Any]
    length: str


@dataclass(frozen=True)
class FlatLayout:
    """The decoding plan of one lcm-gen class: runs of scalars and runs of arrays."""

    name: str
    fingerprint: bytes
    steps: tuple[_Scalars | _Arrays, ...]
    arrays: tuple[str, ...]

    @property
    def head(self) -> tuple[tuple[str, ...], struct.Struct]:
        """The scalars in front of the first array (readable without decoding arrays)."""
        first = self.steps[0]
        if not isinstance(first, _Scalars):
            raise TypeError(f"{self.name} starts with an array")
        return first.names, first.fmt

    @classmethod
    def of(cls, msg_class: type) -> FlatLayout:
        steps: list[_Scalars | _Arrays] = []
        for slot, typename, dims in zip(
            msg_class.__slots__, msg_class.__typenames__, msg_class.__dimensions__, strict=True
        ):
            if typename not in _PRIMITIVES:
                raise TypeError(f"{msg_class.__name__}.{slot}: {typename} is not a flat field")
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


def decode_flat(
    layout: FlatLayout, buf: np.ndarray, start: int, length: int
) -> tuple[dict[str, int], list[tuple[tuple[str, ...], np.ndarray]]]:
    """Decode one message at buf[start:start+length].

    Returns its scalars and, per array run, the run's names with a (len(names), n)
    big-endian view. Raises MalformedMessage instead of reading past the message.
    """
    end = start + length
    if length < 8 or bytes(buf[start : start + 8]) != layout.fingerprint:
        raise MalformedMessage(f"{layout.name}: wrong fingerprint")
    pos = start + 8
    scalars: dict[str, int] = {}
    arrays: list[tuple[tuple[str, ...], np.ndarray]] = []
    for step in layout.steps:
        if isinstance(step, _Scalars):
            if pos + step.fmt.size > end:
                raise MalformedMessage(f"{layout.name}: message too short")
            scalars.update(zip(step.names, step.fmt.unpack_from(buf, pos), strict=True))
            pos += step.fmt.size
        else:
            n = scalars[step.length]
            count = n * len(step.names)
            nbytes = count * step.dtype.itemsize
            if n < 0 or pos + nbytes > end:
                raise MalformedMessage(f"{layout.name}: bad length {step.length}={n}")
            view = buf[pos : pos + nbytes].view(step.dtype).reshape(len(step.names), n)
            arrays.append((step.names, view))
            pos += nbytes
    return scalars, arrays


def concat_columns(
    parts: list[list[tuple[tuple[str, ...], np.ndarray]]], names: tuple[str, ...]
) -> dict[str, np.ndarray]:
    """Concatenate the array runs of many decoded messages into native-endian columns."""
    out: dict[str, np.ndarray] = {}
    if not parts:
        return out
    for run_index, (run_names, first) in enumerate(parts[0]):
        joined = np.concatenate([p[run_index][1] for p in parts], axis=1) if len(parts) > 1 else first
        native = joined.astype(first.dtype.newbyteorder("="))
        for row, name in enumerate(run_names):
            if name in names:
                out[name] = native[row]
    return out
