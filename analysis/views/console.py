"""The console every command prints on, and what happens when its reader goes away.

A reader of stdout may stop early: `skel report RUN | head`, `skel run FILE | grep -m1
FAULT`. rich's own answer is to exit with 1 on the spot, which would end a run without
its STOP, its report or its log, and tell a script with `pipefail` that the command
failed. Here the console goes quiet instead (stdout now leads to /dev/null), the
command finishes what it was doing, and the CLI ends with EXIT_BROKEN_PIPE (errors.py)
because `reader_gone()` says so.
"""

from __future__ import annotations

import os
import select
import sys
from typing import Any

from rich.console import Console

# Not a terminal: rich would render at $COLUMNS or 80 columns and drop the columns of a
# wider table; a file or a CI log has no edge, so it gets every column.
UNLIMITED_WIDTH = 100_000

# stdout is the process's, so whether its reader has gone is too.
_reader_gone = False


def stdout_to_devnull() -> None:
    """Note that stdout's reader is gone, and send what is still written there (a later
    print, Python's flush at exit) to /dev/null, where it cannot fail again."""
    global _reader_gone
    _reader_gone = True
    devnull = os.open(os.devnull, os.O_WRONLY)
    try:
        os.dup2(devnull, sys.stdout.fileno())
    finally:
        os.close(devnull)


def reader_gone() -> bool:
    return _reader_gone


def reader_closed() -> bool:
    """Has stdout's reader closed its end, though nothing was written since? For a
    command that writes only at its end (`skel watch | head` draws its view once, when it
    stops): the writer of a pipe is told by POLLERR, a hung-up terminal by POLLHUP, a
    descriptor closed under us by POLLNVAL. A file never says so."""
    if _reader_gone:
        return True
    poll = select.poll()
    poll.register(sys.stdout.fileno(), 0)  # no event asked: only errors and hang-ups come back
    if any(events & (select.POLLERR | select.POLLHUP | select.POLLNVAL) for _, events in poll.poll(0)):
        stdout_to_devnull()
    return _reader_gone


class OutputConsole(Console):
    """A rich Console that, when the reader of its file is gone, goes quiet and lets the
    command go on (rich's default raises SystemExit(1) from inside the print)."""

    def on_broken_pipe(self) -> None:
        self.quiet = True
        if self.file in (sys.stdout, sys.__stdout__):
            stdout_to_devnull()


def output_console(**options: Any) -> Console:
    """The console a command prints its tables on: a terminal's own width, and for a file
    or a pipe no limit (tables keep every column, lines are not wrapped)."""
    console = OutputConsole(**options)
    return console if console.is_terminal else OutputConsole(width=UNLIMITED_WIDTH, **options)
