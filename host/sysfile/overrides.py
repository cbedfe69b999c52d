"""`-s TARGET=VALUE` overrides of a system file (the paper's interactive descriptors).

Overrides edit the raw YAML document before validation, so an overridden value
passes exactly the checks a written one does. Targets:

    process.NAME.FIELD   dpu.ID.FIELD   buffer.NAME.FIELD   link.NAME.FIELD
    event.NAME.FIELD     run.FIELD      system
(plural section names work too; a process or buffer may be named by its id).
VALUE is a YAML value (`3000`, `wall`, `[3, 5]`); an empty value or `null`
removes the key, so its default applies.
"""

from __future__ import annotations

import copy
from collections.abc import Collection, Mapping, Sequence
from typing import Any

import yaml

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError

from .yamlfile import did_you_mean, safe_load

SECTIONS = {
    "process": "processes", "processes": "processes",
    "dpu": "dpus", "dpus": "dpus",
    "buffer": "buffers", "buffers": "buffers",
    "link": "links", "links": "links",
    "event": "events", "events": "events",
}
_NOUN = {"processes": "process", "dpus": "DPU", "buffers": "buffer", "links": "link", "events": "event"}
_USAGE = ("use process.NAME.FIELD, dpu.ID.FIELD, buffer.NAME.FIELD, link.NAME.FIELD, event.NAME.FIELD, "
          "run.FIELD or system")
# Setting one of these drops the other, so `-s run.duration_s=5` works on a file with `cycles:`.
_EXCLUSIVE = {"cycles": "duration_s", "duration_s": "cycles"}


class OverrideError(SkelError):
    """One override that cannot be applied; str() is the reason."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, override: str, problem: str) -> None:
        self.override = override
        super().__init__(problem)


def apply_overrides(
    doc: Any,
    overrides: Sequence[str],
    fields: Mapping[str, Collection[str]],
    default_links: list[dict[str, Any]],
) -> tuple[dict[str, Any], dict[str, str]]:
    """A copy of `doc` with the overrides applied, and {field path: override} for
    pointing a later validation error back at the override that caused it.

    `fields` maps "processes", "dpus", "buffers", "links", "events", "run" to the keys each
    accepts; `default_links` is what an absent `links:` section means."""
    if not isinstance(doc, dict):
        raise OverrideError(overrides[0], "the system file is not a mapping")
    doc = copy.deepcopy(doc)
    origin: dict[str, str] = {}
    for text in overrides:
        target, sep, raw = text.partition("=")
        if not sep:
            raise OverrideError(text, "expected TARGET=VALUE")
        value = _parse_value(text, raw)
        path, holder, key = _locate(doc, text, target.strip().split("."), fields, default_links)
        if value is None:
            holder.pop(key, None)
        else:
            holder[key] = value
        if path == "run" and key in _EXCLUSIVE and value is not None:
            holder.pop(_EXCLUSIVE[key], None)
        origin[f"{path}.{key}" if path else key] = text
    return doc, origin


def _parse_value(text: str, raw: str) -> Any:
    try:
        return safe_load(raw) if raw.strip() else None
    except (yaml.YAMLError, ValueError, OverflowError) as e:
        problem = getattr(e, "problem", None) or "invalid YAML"
        raise OverrideError(text, f"value is not valid YAML: {problem}") from None


def _locate(
    doc: dict[str, Any],
    text: str,
    parts: list[str],
    fields: Mapping[str, Collection[str]],
    default_links: list[dict[str, Any]],
) -> tuple[str, dict[str, Any], str]:
    """(field path of the holder, the mapping to edit, the key to set)."""
    if parts == ["system"]:
        return "", doc, "system"
    if len(parts) == 2 and parts[0] == "run":
        _check_field(text, "run", parts[1], fields)
        run = doc.get("run")
        if not isinstance(run, dict):
            run = doc["run"] = {}
        return "run", run, parts[1]
    if len(parts) != 3 or parts[0] not in SECTIONS:
        raise OverrideError(text, f"unknown target '{'.'.join(parts)}'; {_USAGE}")
    section, key, field = SECTIONS[parts[0]], parts[1], parts[2]
    _check_field(text, section, field, fields)
    items = doc.get(section)
    if items is None and section == "links":
        items = doc["links"] = copy.deepcopy(default_links)
    if not isinstance(items, list):
        raise OverrideError(text, f"the system file has no {section} list")
    item = _find(section, items, key)
    if item is None:
        how = f"with id {key}" if section == "dpus" else f"named '{key}'"
        raise OverrideError(text, f"no {_NOUN[section]} {how}")
    label = item.get("id") if section == "dpus" else item.get("name")
    return f"{section}.{label}", item, field


def _find(section: str, items: list[Any], key: str) -> dict[str, Any] | None:
    for item in items:
        if not isinstance(item, dict):
            continue
        if section != "dpus" and item.get("name") == key:
            return item
        if section in ("dpus", "processes", "buffers") and key.isdigit() and item.get("id") == int(key):
            return item
    return None


def _check_field(text: str, section: str, field: str, fields: Mapping[str, Collection[str]]) -> None:
    known = fields[section]
    if field not in known:
        noun = "run" if section == "run" else f"a {_NOUN[section]}"
        hint = did_you_mean(field, known) or f"fields: {', '.join(sorted(known))}"
        raise OverrideError(text, f"{noun} has no field '{field}'; {hint}")
