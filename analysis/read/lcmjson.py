"""LCM messages <-> JSON, and a JSON Schema for every lcm-gen type.

MCAP has no LCM encoding and Foxglove cannot decode LCM, so `skel export` writes the
control messages as JSON with jsonschema schemas. Both are derived from the lcm-gen
Python class (__slots__, __typenames__, __dimensions__), never written by hand, so a
field added to lcmtypes/ appears in the export.
"""

from __future__ import annotations

import base64
import functools
import importlib
import operator
from collections.abc import Callable, Iterator
from typing import Any

import numpy as np

from .flatdecode import FlatLayout, decode_many, file_chunks

_JSON_TYPES = {
    "int8_t": "integer",
    "int16_t": "integer",
    "int32_t": "integer",
    "int64_t": "integer",
    "boolean": "boolean",
    "float": "number",
    "double": "number",
    "string": "string",
}


def lcm_class(typename: str) -> type:
    """The generated class of a nested type name such as 'skelmsg.link_t'."""
    module, _, name = typename.rpartition(".")
    return getattr(importlib.import_module(module or "skelmsg"), name)  # type: ignore[no-any-return]


def type_name(cls: type) -> str:
    return f"{cls.__module__.rsplit('.', 1)[0]}.{cls.__name__}"


@functools.cache
def _fields(cls: type) -> list[tuple[str, str, list[Any] | None]]:
    dims = cls.__dimensions__  # type: ignore[attr-defined]
    for slot, d in zip(cls.__slots__, dims, strict=True):  # type: ignore[attr-defined]
        if d is not None and len(d) != 1:
            raise TypeError(f"{cls.__name__}.{slot}: only 1-D arrays are supported")
    return list(zip(cls.__slots__, cls.__typenames__, dims, strict=True))  # type: ignore[attr-defined]


def _item_schema(typename: str) -> dict[str, Any]:
    if typename == "byte":
        return {"type": "integer", "minimum": 0, "maximum": 255}
    if typename in _JSON_TYPES:
        return {"type": _JSON_TYPES[typename]}
    return schema_of(lcm_class(typename), top=False)


def schema_of(cls: type, top: bool = True) -> dict[str, Any]:
    """A JSON Schema (draft 2020-12) describing `to_json(msg)` of a `cls` message."""
    properties: dict[str, Any] = {}
    for slot, typename, dims in _fields(cls):
        if dims is None:
            properties[slot] = _item_schema(typename)
        elif typename == "byte":
            # Foxglove's convention for bytes inside JSON messages.
            properties[slot] = {"type": "string", "contentEncoding": "base64"}
        else:
            properties[slot] = {"type": "array", "items": _item_schema(typename)}
    schema: dict[str, Any] = {
        "title": type_name(cls),
        "type": "object",
        "properties": properties,
        "required": list(properties),
    }
    if top:
        schema = {"$schema": "https://json-schema.org/draft/2020-12/schema", **schema}
    return schema


@functools.cache
def _plan(cls: type) -> tuple[tuple[str, ...], operator.attrgetter[Any], list[tuple[int, str, str, bool]]]:
    """How to_json reads a `cls`: every field at once, then only the ones that are not
    plain values (arrays, bytes, nested types) looked at again."""
    fields = _fields(cls)
    names = tuple(slot for slot, _, _ in fields)
    special = [(i, slot, typename, dims is not None) for i, (slot, typename, dims) in enumerate(fields)
               if dims is not None or (typename not in _JSON_TYPES and typename != "byte")]  # fmt: skip
    return names, operator.attrgetter(*names or ("__class__",)), special


def to_json(msg: Any) -> dict[str, Any]:
    """Every field of a decoded LCM message, as JSON-ready values (nested types as objects)."""
    names, getter, special = _plan(type(msg))
    values = () if not names else getter(msg) if len(names) > 1 else (getter(msg),)
    out = dict(zip(names, values, strict=True))
    for i, slot, typename, array in special:
        value = values[i]
        if not array:
            out[slot] = to_json(value)
        elif typename == "byte":
            out[slot] = base64.b64encode(bytes(value)).decode("ascii")
        elif typename in _JSON_TYPES:
            out[slot] = list(value)
        else:
            out[slot] = [to_json(v) for v in value]
    return out


@functools.cache
def _layout(cls: type) -> FlatLayout | None:
    """How `cls` is read in bulk, its strings and arrays of structs passed over; None when a
    field cannot be (a nested type, a fixed-size array) or is a boolean (an integer to the bulk
    read, where to_json has the generated decoder's true or false)."""
    if "boolean" in cls.__typenames__:  # type: ignore[attr-defined]
        return None
    try:
        return FlatLayout.of(cls, skipping=True)
    except TypeError:
        return None


def to_json_many(cls: type, buf: np.ndarray, starts: np.ndarray, lengths: np.ndarray,
                 release: Callable[[int, int], None] | None = None) -> Iterator[dict[str, Any] | None]:
    """to_json of each `cls` message at buf[starts[i] : starts[i] + lengths[i]], None where it does
    not decode. Read in bulk (flatdecode), without an object each: a long run logs hundreds of
    thousands of status_t, which decoded one by one took 3 s of a 10^7-record export. A message
    with array elements (a status naming lockouts: few) is decoded by the generated decoder, as
    is one the bulk read refuses, so that the generated decoder alone says which are malformed.
    Read a part of the file at a time (flatdecode.file_chunks), `release(start, end)` told after
    each (as decode_many's): read at once, the map's pages of the whole log stayed in memory
    (2.3 GB). One at a time: 2·10^5 statuses' rows made and held at once took 1.5 s."""
    starts, lengths = np.asarray(starts, dtype=np.int64), np.asarray(lengths, dtype=np.int64)
    for lo, hi in file_chunks(starts, starts + lengths):
        yield from _json_rows(cls, buf, starts[lo:hi], lengths[lo:hi])
        if release is not None:
            release(int(starts[lo]), int((starts[lo:hi] + lengths[lo:hi]).max()))


def _json_rows(cls: type, buf: np.ndarray, starts: np.ndarray,
               lengths: np.ndarray) -> Iterator[dict[str, Any] | None]:
    layout = _layout(cls)
    if layout is None:
        for start, length in zip(starts.tolist(), lengths.tolist(), strict=True):
            yield _one(cls, buf, start, length)
        return
    bulk = decode_many(layout, buf, starts, lengths)
    fields = _fields(cls)
    plain = bulk.ok.copy()
    for _, _, dims in fields:
        if dims is not None:
            plain &= bulk.scalars[dims[0]] == 0
    # Only the rows made here are read: a message the bulk read refuses has its strings at 0,
    # which read as a string would be the whole log.
    kept = np.flatnonzero(plain)
    values: list[list[Any]] = []
    for slot, typename, dims in fields:
        if dims is not None:  # no elements (else not plain): an empty array, as to_json gives it
            values.append([""] * len(kept) if typename == "byte" else [[] for _ in kept])
        elif typename == "string":
            # its byte count, then its bytes; the generated decoder drops the last (the NUL)
            first, end = (a[kept].tolist() for a in bulk.passed[slot])
            values.append([buf[a + 4 : b - 1].tobytes().decode("utf-8", "replace")
                           for a, b in zip(first, end, strict=True)])  # fmt: skip
        else:
            values.append(bulk.scalars[slot][kept].tolist())
    names = [slot for slot, _, _ in fields]
    made = (dict(zip(names, row, strict=True)) for row in zip(*values, strict=True))
    for i, is_plain in enumerate(plain.tolist()):
        yield next(made) if is_plain else _one(cls, buf, int(starts[i]), int(lengths[i]))


def _one(cls: type, buf: np.ndarray, start: int, length: int) -> dict[str, Any] | None:
    try:
        msg = cls.decode(buf[start : start + length].tobytes())  # type: ignore[attr-defined]
    except Exception:  # any decoder failure means "malformed", never a crash
        return None
    return to_json(msg)
