"""The shell blocks of a documentation page, as the reader sees them.

A fenced block tagged `sh` is commands to run, each of which must succeed; one tagged
`console` is `$ command` lines, each followed by lines of what it prints: of those, the lines
without a digit (headers, verdict words) must appear in its output, whatever its exit status;
lines with figures (times, percentages) are what one run printed and are not compared. A block
whose title starts with `several machines` needs a lab and is listed, not run; one whose
title is `on MACHINE[, MACHINE and MACHINE]` or `on every machine` is a step of the lab
tutorial, run on namespaces standing for those machines (test_lab_tutorial.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path

FENCE = re.compile(r"^```(sh|console)([^\n]*)\n(.*?)^```[ \t]*$", re.MULTILINE | re.DOTALL)
TITLE = re.compile(r'title="([^"]*)"')
NOT_HERE = "several machines"
MACHINE = re.compile(r"\brt-[a-z]\b")
EVERY_MACHINE = "on every machine"


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
        """Run on this machine, in one namespace (not a lab's step, not a lab's set-up)."""
        return not self.title.startswith((NOT_HERE, "on "))

    @property
    def not_run(self) -> bool:
        """Shown, never run: it needs real machines (installing, systemd, copying a key)."""
        return self.title.startswith(NOT_HERE)

    def machines(self, every: list[str]) -> list[str]:
        """The lab machines a step runs on ([] for a block that is not a lab step)."""
        if self.title == EVERY_MACHINE:
            return every
        return MACHINE.findall(self.title) if self.title.startswith("on ") else []

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
