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


def test_the_bare_frame_builds_and_counts_its_frames() -> None:
    """bench/frame.c, the rate part's bare frame: built as make bench builds it, 0.1 s at 1 kHz
    in SCHED_OTHER (priority 0) on CPU 0: every frame counted, and a frame asked for more work
    than its period overruns every time."""
    sys.path.insert(0, str(REPO / "bench"))
    from run import build_c

    exe = build_c("frame")

    def frame(period_us: str, work_us: str) -> subprocess.CompletedProcess[str]:
        return subprocess.run([str(exe), period_us, work_us, "4", "0.1", "0", "0"], capture_output=True,
                              text=True, timeout=30)  # fmt: skip

    fits, over, bad = frame("1000", "10"), frame("1000", "300"), frame("0", "10")
    assert fits.returncode == 0, fits.stderr
    frames, overran, unexplained = map(int, fits.stdout.split())
    assert frames == 100 and 0 <= unexplained <= overran <= frames
    # Each frame is late by its own work, no stall of the machine's: none explained
    assert over.returncode == 0 and over.stdout.split() == ["100", "100", "100"], over.stderr
    assert bad.returncode == 2 and bad.stderr.strip() == "frame: bad argument"
