"""Reading a system file and reporting its errors as one actionable line.

Every problem with a system file becomes a SystemFileError whose text is
`FILE: field.path: problem`, with list items named by their `name` (or a DPU by
its id) so the user finds the line without counting. The schema itself lives
in schema.py; this module only knows how to read YAML and word errors.

Size, nesting depth and the number of values (aliases expanded) are limited before
the document is built: PyYAML builds nested nodes recursively (a list nested 500
deep was a RecursionError traceback), an alias bomb expands exponentially, and a
25 MB file took minutes and gigabytes. libyaml's parser, when PyYAML has it, does
the counting pass and the load quickly; PyYAML's own parser words a syntax error.
"""

from __future__ import annotations

import difflib
import typing
from collections.abc import Collection, Iterator, Mapping
from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError

# Lists whose items are named by a key instead of an index in error paths.
NAMED_BY = {"dpus": "id", "processes": "name", "buffers": "name", "links": "name", "chains": "name",
            "events": "name"}

# The whole system goes to every DPU in one config_t of about 1.5 times the file's size;
# above 128 KiB it would outgrow a socket's default receive buffer (212 KB) before it
# reached a DPU. A system of 800 processes (examples/scale-16x2.yaml's style) fits.
MAX_BYTES = 128 * 1024
# A system file is 5 levels deep (processes -> a process -> its inputs); room for flow style.
MAX_DEPTH = 32
# Values once every alias is expanded: more than 128 KiB of `[1,1,...]` holds, far fewer
# than an alias bomb makes.
MAX_VALUES = 200_000
_FAST_LOADER: type = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
REWORD_BYTES = 32 * 1024  # up to this size PyYAML's parser words a syntax error (0.2 s at most)


class SystemFileError(SkelError):
    """A system file (or an override of it) that cannot be used, as one line."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, file: str | Path, where: str, problem: str) -> None:
        self.file = str(file)
        self.where = where
        # One line, always: the CLI prints it as is and tests compare it.
        self.problem = " ".join(str(problem).split())
        super().__init__(f"{self.file}: {where}: {self.problem}")

    def line(self) -> str:
        return str(self)  # it names its file: no "skel:" before it


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


class _FastUniqueKeyLoader(_FAST_LOADER):  # type: ignore[misc, valid-type]
    """The same, on libyaml's parser when PyYAML has it (about 4 times faster)."""


_FastUniqueKeyLoader.add_constructor(yaml.resolver.BaseResolver.DEFAULT_MAPPING_TAG, _construct_mapping)


def read_yaml(path: str | Path) -> tuple[str, Any]:
    """The file's text and its YAML document; SystemFileError when unreadable, too large
    or not YAML."""
    try:
        with Path(path).open("rb") as f:
            # Never more than the limit: the file may be huge, or a device that never ends.
            data = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise SystemFileError(path, "cannot read", e.strerror or str(e)) from None
    if len(data) > MAX_BYTES:
        raise SystemFileError(path, "size", f"more than {MAX_BYTES // 1024} KiB; a system file may have "
                              f"at most {MAX_BYTES} bytes (its config must reach the DPUs in one message)")
    try:
        text = data.decode("utf-8")
    except UnicodeDecodeError as e:
        raise SystemFileError(path, "cannot read", f"not UTF-8 text ({e.reason} at byte {e.start})") from None
    return text, parse_yaml(path, text)


def safe_load(text: str) -> Any:
    """The YAML document in `text`, within MAX_BYTES, MAX_DEPTH and MAX_VALUES; duplicate keys
    refused. Raises yaml.YAMLError (a limit is a MarkedYAMLError at the place it was passed)."""
    if len(text) > MAX_BYTES:
        raise yaml.MarkedYAMLError(problem=f"{len(text)} characters, more than {MAX_BYTES}")
    try:
        _check_shape(yaml.parse(text, Loader=_FAST_LOADER))
        return yaml.load(text, Loader=_FastUniqueKeyLoader)
    except yaml.YAMLError as fast_error:
        if isinstance(fast_error, yaml.MarkedYAMLError) and fast_error.note == _LIMIT:
            raise
        # A syntax error: PyYAML's own parser words it better than libyaml (and the same on
        # every machine), at a quarter of the speed: for a file that is not small, libyaml's.
        if _FAST_LOADER is yaml.SafeLoader or len(text) > REWORD_BYTES:
            raise
        yaml.load(text, Loader=_UniqueKeyLoader)
        raise fast_error from None  # PyYAML read what libyaml did not: report libyaml's reason


_LIMIT = "limit"  # the note of an error raised by _check_shape


def _check_shape(events: Iterator[yaml.Event]) -> None:
    """Refuse a document nested deeper than MAX_DEPTH or holding more than MAX_VALUES values
    once aliases are expanded, as soon as the parser's events show it."""
    values = 0
    # Per open collection: [values before it, its anchor, its level, the deepest level within].
    open_: list[list[Any]] = []
    named: dict[str, tuple[int, int]] = {}   # anchor -> (values, levels) of what it names

    def limit(event: yaml.Event, problem: str) -> yaml.MarkedYAMLError:
        return yaml.MarkedYAMLError(problem=problem, problem_mark=event.start_mark, note=_LIMIT)

    for event in events:
        level = len(open_)
        if isinstance(event, yaml.CollectionStartEvent):
            if level + 1 > MAX_DEPTH:
                raise limit(event, f"nested more than {MAX_DEPTH} levels deep")
            open_.append([values, event.anchor, level + 1, level + 1])
            values += 1
        elif isinstance(event, yaml.CollectionEndEvent):
            before, anchor, own, deepest = open_.pop()
            if anchor is not None:
                named[anchor] = (values - before, deepest - own + 1)
            if open_:
                open_[-1][3] = max(open_[-1][3], deepest)
        elif isinstance(event, yaml.ScalarEvent):
            values += 1
            if event.anchor is not None:
                named[event.anchor] = (1, 0)
        elif isinstance(event, yaml.AliasEvent):
            count, levels = named.get(event.anchor or "", (1, 0))
            values += count
            if level + levels > MAX_DEPTH:
                raise limit(event, f"alias *{event.anchor} nests more than {MAX_DEPTH} levels deep")
            if open_:
                open_[-1][3] = max(open_[-1][3], level + levels)
        if values > MAX_VALUES:
            raise limit(event, f"more than {MAX_VALUES} values once aliases are expanded")


def parse_yaml(path: str | Path, text: str) -> Any:
    try:
        return safe_load(text)
    except yaml.MarkedYAMLError as e:
        mark = e.problem_mark or e.context_mark
        where = f"line {mark.line + 1} column {mark.column + 1}" if mark else "YAML"
        problem = e.problem or "invalid YAML"
        if e.context:
            problem = f"{problem} ({e.context})"
        raise SystemFileError(path, where, problem) from None
    except yaml.reader.ReaderError as e:
        line = text.count("\n", 0, e.position) + 1
        column = e.position - (text.rfind("\n", 0, e.position) + 1) + 1
        raise SystemFileError(path, f"line {line} column {column}",
                              f"character #x{e.character:04x} is not allowed in YAML ({e.reason})") from None
    except yaml.YAMLError as e:
        raise SystemFileError(path, "YAML", str(e)) from None
    except (ValueError, OverflowError) as e:  # a value PyYAML's constructors refuse (an int of 5000 digits)
        raise SystemFileError(path, "YAML", f"a value cannot be read: {str(e).split(':')[0]}") from None


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
        if isinstance(part, str) and part.startswith("<"):
            continue  # a union's tag (schema.Compute), not a key of the file
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


def did_you_mean(word: str, known: Collection[str]) -> str | None:
    """"did you mean 'X'?" for the known name closest to a misspelt one, if one is close."""
    near = difflib.get_close_matches(word, list(known), n=1)
    return f"did you mean '{near[0]}'?" if near else None


def describe(error: Mapping[str, Any], root: type[BaseModel]) -> str:
    """A pydantic error as a sentence a user can act on."""
    kind, value, ctx = error["type"], error.get("input"), error.get("ctx") or {}
    if kind == "extra_forbidden":
        loc = tuple(error["loc"])
        keys = sorted(known_keys(root, loc[:-1]))
        return f"unknown key; {did_you_mean(str(loc[-1]), keys) or 'expected one of: ' + ', '.join(keys)}"
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
