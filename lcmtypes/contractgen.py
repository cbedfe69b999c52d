"""Generate the wire contract's constants for C and Python from lcmtypes/contract.txt.

Channel names, the default URL and the limits both sides enforce are written once,
in contract.txt (LCM has no string constants, and these belong to no one message).
This writes them as the C header the DPU includes and as the Python module
`skelmsg.contract` the host tool and the analysis import:

    contractgen.py --c DIR      lcmtypes/contract.txt  ->  DIR/skelmsg_contract.h
    contractgen.py --python DIR lcmtypes/contract.txt  ->  DIR/contract.py

A line is `NAME = "text"`, `NAME = integer` (a product of integers allowed) or `NAME = decimal`
(`0.001`, `1e-6`: a limit on a double), then an optional `# comment`; blank lines and lines
starting with `#` are skipped. A size on the wire is computed from the .lcm file beside this one,
never written by hand: `NAME = sizeof(seal_t)` is a fixed-size message's whole encoding,
`NAME = offsetof(buffer_t, payload)` the bytes of its encoding before that field; both count
LCM's 8-byte fingerprint.
"""

from __future__ import annotations

import argparse
import math
import re
from dataclasses import dataclass
from pathlib import Path

INTEGER = r"[0-9][0-9_]*"
DECIMAL = r"[0-9]+(?:\.[0-9]+(?:[eE]-?[0-9]+)?|[eE]-?[0-9]+)"  # a point or an exponent: never an integer
LAYOUT = re.compile(r"(?P<op>sizeof|offsetof)\(\s*(?P<type>\w+)\s*(?:,\s*(?P<field>\w+)\s*)?\)")
LINE = re.compile(rf'(?P<name>[A-Z][A-Z0-9_]*)\s*=\s*'
                  rf'(?P<value>"[^"\\]*"|{DECIMAL}|{INTEGER}(?:\s*\*\s*{INTEGER})*|{LAYOUT.pattern})'
                  r"\s*(?:#\s*(?P<doc>.*))?")
FINGERPRINT_BYTES = 8  # LCM's first 8 bytes of every encoding
PRIMITIVE_BYTES = {"int8_t": 1, "byte": 1, "boolean": 1, "int16_t": 2, "int32_t": 4, "int64_t": 8,
                   "float": 4, "double": 8}
C_PREFIX = "SKEL_"
INT32_MAX = 2**31 - 1


@dataclass(frozen=True)
class Constant:
    name: str
    value: str | int | float
    written: str  # as in contract.txt: "4 * 1024 * 1024"
    doc: str


def layout_bytes(folder: Path, message: str, field: str | None) -> int:
    """The bytes of MESSAGE's encoding before FIELD (all of them when None), from its .lcm file:
    each field up to there must have a fixed size (a primitive, or an array of a given length)."""
    path = folder / f"{message}.lcm"
    body = re.search(r"struct\s+(\w+)\s*\{(.*?)\}", re.sub(r"//.*", "", path.read_text()), re.S)
    if body is None or body[1] != message:
        raise SystemExit(f"{path}: no struct {message}")
    size = FINGERPRINT_BYTES
    for decl in filter(None, (d.strip() for d in body[2].split(";"))):
        kind, name, count = re.fullmatch(r"(\w+)\s+(\w+)\s*(?:\[\s*(\w+)\s*\])?", decl).groups()
        if name == field:
            return size
        if kind not in PRIMITIVE_BYTES or (count is not None and not count.isdigit()):
            raise SystemExit(f"{path}: {message}.{name} ({decl}) has no fixed size")
        size += PRIMITIVE_BYTES[kind] * (int(count) if count else 1)
    if field is not None:
        raise SystemExit(f"{path}: {message} has no field {field}")
    return size


def _layout(path: Path, number: int, written: str) -> int:
    layout = LAYOUT.fullmatch(written)
    assert layout is not None  # LINE matched it
    if (layout["op"] == "offsetof") != (layout["field"] is not None):
        raise SystemExit(f"{path}:{number}: sizeof(message) or offsetof(message, field), got '{written}'")
    return layout_bytes(path.parent, layout["type"], layout["field"])


def parse(path: Path) -> list[Constant]:
    constants: list[Constant] = []
    seen: set[str] = set()
    for number, raw in enumerate(path.read_text().splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        match = LINE.fullmatch(line)
        if match is None:
            raise SystemExit(f"{path}:{number}: expected NAME = \"text\", NAME = integer or NAME = decimal, "
                             f"got '{line}'")
        name, written = match["name"], match["value"]
        if name in seen:
            raise SystemExit(f"{path}:{number}: {name} is defined twice")
        seen.add(name)
        value: str | int | float = (written[1:-1] if written.startswith('"')
                                    else float(written) if re.fullmatch(DECIMAL, written)
                                    else _layout(path, number, written) if "(" in written
                                    else math.prod(int(f) for f in written.split("*")))
        constants.append(Constant(name, value, written, (match["doc"] or "").strip()))
    return constants


def c_literal(value: str | int | float) -> str:
    if isinstance(value, str):
        return f'"{value}"'
    if isinstance(value, float):
        return repr(value)  # a double literal ("0.001", "1e-06"), read back exactly
    return str(value) if value <= INT32_MAX else f"{value}LL"


def c_header(constants: list[Constant], source: str) -> str:
    lines = [f"/* Generated by lcmtypes/contractgen.py from {source}: do not edit. */",
             "#ifndef SKELMSG_CONTRACT_H", "#define SKELMSG_CONTRACT_H", ""]
    for c in constants:
        doc = ": ".join(part for part in (c.written if "*" in c.written or "(" in c.written else "", c.doc)
                        if part)
        comment = f" /* {doc.replace('*/', '* /')} */" if doc else ""
        lines.append(f"#define {C_PREFIX}{c.name} {c_literal(c.value)}{comment}")
    return "\n".join([*lines, "", "#endif", ""])


def python_module(constants: list[Constant], source: str) -> str:
    lines = [f'"""The wire contract\'s names and limits (generated by lcmtypes/contractgen.py from {source}:',
             'do not edit)."""', ""]
    for c in constants:
        comment = f"  # {c.doc}" if c.doc else ""
        value = c_literal(c.value) if isinstance(c.value, str) else repr(c.value)
        lines.append(f"{c.name} = {value}{comment}")
    return "\n".join([*lines, ""])


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--c", type=Path, help="write DIR/skelmsg_contract.h")
    parser.add_argument("--python", type=Path, help="write DIR/contract.py")
    parser.add_argument("file", type=Path)
    args = parser.parse_args()
    constants = parse(args.file)
    source = f"lcmtypes/{args.file.name}"
    for out, name, text in ((args.c, "skelmsg_contract.h", c_header),
                            (args.python, "contract.py", python_module)):
        if out is not None:
            out.mkdir(parents=True, exist_ok=True)
            (out / name).write_text(text(constants, source))


if __name__ == "__main__":
    main()
