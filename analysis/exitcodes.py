"""The exit codes of every `skel` command, defined once.

In analysis/ because both halves of the tool return them and analysis/ never
imports host/; the documentation's exit-code table is generated from the names and the
comments below (docs/hooks.py).
"""

from __future__ import annotations

EXIT_OK = 0            # a clean run: no fatal flaw measured, nothing failed
EXIT_FAILED = 1        # an operation failed: a DPU silent or lost, a push rejected, no run heard
EXIT_BAD_INPUT = 2     # a file or option that cannot be used: one line `FILE: field.path: problem`
EXIT_FATAL_FLAW = 3    # a fatal flaw: lockout, jam, skipping, or a DPU behind the platform does not explain
EXIT_INTERRUPTED = 130  # Ctrl-C or SIGTERM: 128 + SIGINT, as shells report a command ended by Ctrl-C
EXIT_BROKEN_PIPE = 141  # the reader of its output stopped (`| head`): 128 + SIGPIPE, as a killed `cat`
