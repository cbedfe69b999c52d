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
from typing import Any

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
