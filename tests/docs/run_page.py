"""Runs one page's shell blocks in order, in the current directory, and stops at the first
that fails: `python run_page.py PAGE.md`. tests/docs/test_shell_blocks.py starts it inside a
network namespace of its own, so the page's default multicast URL is heard by nothing else.
Prints one JSON line per command: what ran, its exit status, how long, and what was missing.
"""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path

from blocks import blocks


def main(page: Path) -> int:
    for block in blocks(page):
        if not block.runs_here:
            continue
        for command in block.commands():
            start = time.monotonic()
            done = subprocess.run(["bash", "-e", "-o", "pipefail", "-c", command.line],
                                  capture_output=True, text=True, timeout=240)
            said = " ".join((done.stdout + done.stderr).split())
            missing = [line for line in command.expect if line not in said]
            failed = bool(missing) or (block.kind == "sh" and done.returncode != 0)
            print(json.dumps({"line": block.line, "command": command.line, "status": done.returncode,
                              "seconds": round(time.monotonic() - start, 1), "missing": missing,
                              "failed": failed, "output": (done.stdout + done.stderr)[-4000:]}),
                  flush=True)
            if failed:
                return 1
    return 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
