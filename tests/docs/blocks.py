"""The shell blocks of a documentation page, as the reader sees them.

A fenced block tagged `sh` is commands to run, each of which must succeed; one tagged
`console` is `$ command` lines, each followed by lines of what it prints: of those, the lines
without a digit (headers, verdict words) must appear in its output, whatever its exit status;
lines with figures (times, percentages) are what one run printed and are not compared. A block
whose title starts with `several machines` needs a lab and is listed, not run.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

FENCE = re.compile(r"^```(sh|console)([^\n]*)\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
TITLE = re.compile(r'title="([^"]*)"')
NOT_HERE = "several machines"


@dataclass
class Command:
    line: str
    expect: list[str] = field(default_factory=list)  # console: lines its output must hold


@dataclass
class Block:
    page: Path
    line: int           # where the block starts in its page, from 1
    kind: str           # sh | console
    title: str
    text: str

    @property
    def runs_here(self) -> bool:
        return not self.title.startswith(NOT_HERE)

    def commands(self) -> list[Command]:
        if self.kind == "sh":
            return [Command(self.text)]
        out: list[Command] = []
        for line in self.text.splitlines():
            if line.startswith("$ "):
                out.append(Command(line[2:]))
            elif out and line.strip() and line.strip() != "..." and not re.search(r"\d", line):
                out[-1].expect.append(" ".join(line.split()))
        return out


def blocks(page: Path) -> list[Block]:
    text = page.read_text()
    found = []
    for m in FENCE.finditer(text):
        title = TITLE.search(m.group(2))
        found.append(Block(page, text.count("\n", 0, m.start()) + 1, m.group(1),
                           title.group(1) if title else "", m.group(3)))
    return found
