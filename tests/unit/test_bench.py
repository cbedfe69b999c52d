"""`make bench`'s driver, as a smoke: its figures are make bench's, but what it prints must not
rot between its runs. Two of its cheap parts, small, into a folder of the test's own."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

from conftest import REPO


def test_each_part_states_its_goal_its_verdict_and_the_machine_it_ran_on(tmp_path: Path) -> None:
    tree = {p: p.read_bytes() for p in (REPO / "bench" / "results").iterdir()}
    done = subprocess.run([sys.executable, "bench/run.py", "--parts", "logreader,allocate",
                           "--records", "20000", "--allocate-seconds", "0.2", "--results", str(tmp_path)],
                          cwd=REPO, capture_output=True, text=True, timeout=300)  # fmt: skip
    assert done.returncode == 0, done.stderr
    for part in ("logreader", "allocate"):
        lines = (tmp_path / f"{part}.txt").read_text().splitlines()
        assert "goal" in lines[0] and re.search(r": (PASS|FAIL)\b", lines[0]), lines[0]
        assert lines[-1].startswith("# machine: "), lines[-1]
    assert not (tmp_path / "summary.txt").exists()  # only a run of every part writes it
    last = done.stdout.rstrip().splitlines()[-1]
    assert re.fullmatch(r"logreader, allocate: \d+\.\d min \(the 15 min goal is for every part\)", last), last
    assert {p: p.read_bytes() for p in (REPO / "bench" / "results").iterdir()} == tree  # left alone
