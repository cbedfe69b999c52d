"""Edits to a system file's text that keep everything else as the user wrote it (comments,
order, flow or block style): set a key of a mapping, add an item to a sequence. PyYAML's
composer gives each node's place in the text; edits are applied from the end backwards.
"""

from __future__ import annotations

import yaml

Edit = tuple[int, int, str]  # replace text[start:end] with this


def root(text: str) -> yaml.MappingNode:
    node = yaml.compose(text)
    assert isinstance(node, yaml.MappingNode)
    return node


def value(mapping: yaml.MappingNode, key: str) -> yaml.Node | None:
    return next((v for k, v in mapping.value if k.value == key), None)


def set_key(text: str, mapping: yaml.MappingNode, key: str, new: str) -> Edit:
    """Replace KEY's value, or add KEY after the mapping's last entry."""
    found = value(mapping, key)
    if found is not None:
        return found.start_mark.index, found.end_mark.index, new
    at = _end(text, mapping.value[-1][1])
    if mapping.flow_style:
        return at, at, f", {key}: {new}"
    at = _line_end(text, at)  # after a comment on that line
    return at, at, f"\n{' ' * mapping.value[0][0].start_mark.column}{key}: {new}"


def remove_key(text: str, mapping: yaml.MappingNode, key: str) -> Edit | None:
    """Take KEY and its value out of the mapping, with what joined it to its neighbours (a flow
    mapping's comma, a block mapping's line); None when the mapping has no KEY."""
    pairs = mapping.value
    at = next((i for i, (k, _) in enumerate(pairs) if k.value == key), None)
    if at is None:
        return None
    name, found = pairs[at]
    if at == 0:
        end = pairs[1][0].start_mark.index if len(pairs) > 1 else _end(text, found)
        return name.start_mark.index, end, ""
    if mapping.flow_style:
        return _end(text, pairs[at - 1][1]), _end(text, found), ""
    return text.rfind("\n", 0, name.start_mark.index), _line_end(text, _end(text, found)), ""


def append_item(text: str, sequence: yaml.SequenceNode, item: str) -> Edit:
    """Add ITEM (flow YAML, one line) after the sequence's last item."""
    last = sequence.value[-1]
    at = _end(text, last)
    if sequence.flow_style:
        return at, at, f", {item}"
    line = text[text.rfind("\n", 0, last.start_mark.index) + 1:last.start_mark.index]
    dash = line.rfind("-")
    at = _line_end(text, at)
    return at, at, f"\n{line[:dash]}- {item}"


def _end(text: str, node: yaml.Node) -> int:
    """Where NODE's text ends: a block node's end mark is past its line's newline."""
    at = node.end_mark.index
    while at > node.start_mark.index and text[at - 1] in "\n ":
        at -= 1
    return at


def _line_end(text: str, at: int) -> int:
    end = text.find("\n", at)
    return len(text) if end < 0 else end


def apply(text: str, edits: list[Edit]) -> str:
    for start, end, new in sorted(edits, reverse=True):
        text = text[:start] + new + text[end:]
    return text


def with_overrides(text: str, overrides: list[str]) -> str:
    """TEXT with `-s TARGET=VALUE` overrides (overrides.py) written into it, keeping everything
    else as the user wrote it: the console's Save. VALUE is written as given (YAML); a target
    the text does not spell out (a DPU's absent section, an empty value that removes a key)
    is a ValueError naming it: the caller validates the result against load() with the same
    overrides, so what is saved is what was predicted."""
    for override in overrides:
        target, _, raw = override.partition("=")
        if not raw.strip():
            raise ValueError(f"{override}: removing a key is not written into the file; set a value")
        node = _holder(root(text), target.strip().split("."))
        if node is None:
            raise ValueError(f"{override}: the file spells out no such item to edit")
        holder, key = node
        text = apply(text, [set_key(text, holder, key, raw.strip())])
    return text


def process_item(top: yaml.MappingNode, name: str) -> yaml.MappingNode | None:
    """The mapping of the process named NAME (or of id NAME), when the file spells one out."""
    found = _holder(top, ["process", name, "name"])
    return found[0] if found is not None else None


def _holder(top: yaml.MappingNode, parts: list[str]) -> tuple[yaml.MappingNode, str] | None:
    from .overrides import SECTIONS

    if parts == ["system"]:
        return top, "system"
    if len(parts) == 2 and parts[0] == "run":
        run = value(top, "run")
        return (run, parts[1]) if isinstance(run, yaml.MappingNode) and run.value else None
    if len(parts) != 3 or parts[0] not in SECTIONS:
        return None
    section, key, field = SECTIONS[parts[0]], parts[1], parts[2]
    items = value(top, section)
    if not isinstance(items, yaml.SequenceNode):
        return None
    for item in items.value:
        if not isinstance(item, yaml.MappingNode) or not item.value:
            continue
        name, ident = value(item, "name"), value(item, "id")
        if (section != "dpus" and name is not None and name.value == key) or (
                section in ("dpus", "processes", "buffers") and ident is not None and ident.value == key):
            return item, field
    return None
