"""The exit codes of every `skel` command, and the one base of skeleton's own errors.

Here, at the bottom of analysis/, because every layer of host/ and analysis/ may import it
(analysis/ never imports host/ beyond its model). The documentation's exit-code table is
generated from the names and the comments below (docs/hooks.py).
"""

from __future__ import annotations

EXIT_OK = 0            # a clean run: no fatal flaw measured, nothing failed
EXIT_FAILED = 1        # an operation failed: a DPU silent or lost, a push rejected, no run heard
EXIT_BAD_INPUT = 2     # a file or option that cannot be used: one line `FILE: field.path: problem`
EXIT_FATAL_FLAW = 3    # a fatal flaw: a lockout, jam, skipping or DPU behind the platform does not explain
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM: 128 + SIGINT, as shells report a command ended by Ctrl-C
EXIT_BROKEN_PIPE = 141  # the reader of its output stopped (`| head`): 128 + SIGPIPE, as a killed `cat`


class SkelError(Exception):
    """Every error skeleton raises of its own: one line for the user (`line()`, never a
    traceback) and the exit code `skel` ends with when nothing nearer handled it."""

    exit_code = EXIT_FAILED

    def line(self) -> str:
        return f"skel: {self}"
