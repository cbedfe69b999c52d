"""Reading a system file and reporting its errors as one actionable line.

Every problem with a system file becomes a SystemFileError whose text is
`FILE: field.path: problem`, with list items named by their `name` (or a DPU by
its id) so the user finds the line without counting. The schema itself lives
in system.py; this module only knows how to read YAML and word errors.
"""

from __future__ import annotations

import difflib
import typing
from collections.abc import Collection, Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

# Lists whose items are named by a key instead of an index in error paths.
NAMED_BY = {"dpus": "id", "processes": "name", "buffers": "name", "links": "name", "chains": "name"}


class SystemFileError(Exception):
    """A system file (or an override of it) that cannot be used, as one line."""

    def __init__(self, file: str | Path, where: str, problem: str) -> None:
        self.file = str(file)
        self.where = where
        # One line, always: the CLI prints it as is and tests compare it.
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{self.file}: {where}: {self.problem}")


class _UniqueKeyLoader(yaml.SafeLoader):
    """SafeLoader that refuses duplicate keys: PyYAML silently keeps the last one,
    which hides exactly the kind of slip (two `compute_us:` lines) we must catch."""


def _construct_mapping(loader: _UniqueKeyLoader, node: yaml.MappingNode) -> dict[Any, Any]:
    seen: set[Any] = set()
    for key_node, _ in node.value:
        key = loader.construct_object(key_node, deep=True)
        try:
            if key in seen:
                raise yaml.constructor.ConstructorError(
                    None, None, f"duplicate key {key!r}", key_node.start_mark
                )
            seen.add(key)
        except TypeError:  # unhashable key: let PyYAML word it
            break
    return loader.construct_mapping(node, deep=True)


_UniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read_yaml(path: str | Path) -> tuple[str, Any]:
    """The file's text and its YAML document; SystemFileError when unreadable or not YAML."""
    try:
        text = Path(path).read_text(encoding="utf-8")
    except OSError as e:
        raise SystemFileError(path, "cannot read", e.strerror or str(e)) from None
    except UnicodeDecodeError as e:
        raise SystemFileError(path, "cannot read", f"not UTF-8 text ({e.reason})") from None
    return text, parse_yaml(path, text)


def parse_yaml(path: str | Path, text: str) -> Any:
    try:
        return yaml.load(text, Loader=_UniqueKeyLoader)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f"line {mark.line + 1} column {mark.column + 1}" if mark else "YAML"
        problem = e.problem or "invalid YAML"
        if e.context:
            problem = f"{problem} ({e.context})"
        raise SystemFileError(path, where, problem) from None
    except yaml.YAMLError as e:
        raise SystemFileError(path, "YAML", str(e)) from None


def show(value: Any) -> str:
    """A value as the user wrote it, short."""
    if value is None:
        return "null"
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, Mapping):
        return "a mapping"
    if isinstance(value, list):
        return "a list"
    text = repr(value) if isinstance(value, str) else f"{value:g}" if isinstance(value, float) else str(value)
    return text if len(text) <= 60 else text[:57] + "..."


def field_path(loc: tuple[Any, ...], doc: Any) -> str:
    """`processes.executor.inputs[2]` from pydantic's ('processes', 3, 'inputs', 2)."""
    out = ""
    node = doc
    for depth, part in enumerate(loc):
        if isinstance(node, list) and isinstance(part, int):
            item = node[part] if 0 <= part < len(node) else None
            label = _label(loc[depth - 1] if depth == 1 else None, item)
            out += f".{label}" if label is not None else f"[{part}]"
            node = item
        elif isinstance(node, list) and part == "processes":
            continue  # a chain written as a plain list has no `processes:` key
        else:
            out += f".{part}" if out else str(part)
            node = node.get(part) if isinstance(node, Mapping) else None
    return out or "top level"


def _label(section: Any, item: Any) -> str | None:
    key = NAMED_BY.get(section) if isinstance(section, str) else None
    if key is None or not isinstance(item, Mapping):
        return None
    value = item.get(key)
    if isinstance(value, bool) or not isinstance(value, int | str) or value == "":
        return None
    return str(value)


def known_keys(model: type[BaseModel], loc: tuple[Any, ...]) -> Collection[str]:
    """The keys the model nested at `loc` accepts (for 'did you mean')."""
    for part in loc:
        if not isinstance(part, str) or part not in model.model_fields:
            continue
        inner = _model_in(model.model_fields[part].annotation)
        if inner is None:
            break
        model = inner
    return model.model_fields.keys()


def _model_in(annotation: Any) -> type[BaseModel] | None:
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return annotation
    for arg in typing.get_args(annotation):
        found = _model_in(arg)
        if found is not None:
            return found
    return None


def describe(error: Mapping[str, Any], root: type[BaseModel]) -> str:
    """A pydantic error as a sentence a user can act on."""
    kind, value, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    if kind == "extra_forbidden":
        loc = tuple(error["loc"])
        keys = sorted(known_keys(root, loc[:-1]))
        near = difflib.get_close_matches(str(loc[-1]), keys, n=1)
        if near:
            return f"unknown key; did you mean '{near[0]}'?"
        return f"unknown key; expected one of: {', '.join(keys)}"
    simple = {
        "missing": "required key is missing",
        "int_type": "must be an integer",
        "int_from_float": "must be an integer",
        "float_type": "must be a number",
        "string_type": "must be a string",
        "bool_type": "must be true or false",
        "list_type": "must be a list",
        "dict_type": "must be a mapping",
        "model_type": "must be a mapping",
        "model_attributes_type": "must be a mapping",
    }
    if kind == "missing":
        return simple[kind]
    if kind in simple:
        return f"{simple[kind]}, got {show(value)}"
    if kind == "literal_error":
        return f"must be one of {ctx.get('expected', '?')}, got {show(value)}"
    if kind == "value_error":
        return str(ctx.get("error", error["msg"]))
    if kind == "too_short":
        return f"needs at least {ctx.get('min_length')} item(s)"
    return f"{error['msg']}, got {show(value)}"
