"""tests/unit/test_allocate.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import EXAMPLES, DpuFarm, skel


@pytest.mark.timing
def test_servo_at_2_5_ms_with_what_would_runs_without_lockout(tmp_path: Path, url: str) -> None:
    out = tmp_path / "fixed.yaml"
    done = skel("allocate", str(EXAMPLES / "servo-2.5ms.yaml"), "--dpus", "5", "--speed", "1.56",
                "--max-load", "90", "--out", str(out), "--verify", "--url", url, timeout=240)
    assert done.returncode == 0, done.stdout + done.stderr
    assert f"{EXAMPLES / 'servo-2.5ms.yaml'} ran, exit 3" in done.stdout  # the paper's jam
    assert f"{out} ran, exit 0" in done.stdout
    assert "per DPU: B - A" in done.stdout  # skel diff of the two runs


def test_verify_says_why_a_run_did_not_start_and_compares_nothing(tmp_path: Path, url: str,
                                                                  dpus: DpuFarm) -> None:
    """--verify spawns its DPUs: beside DPU 1 already up, the first run is refused, and that
    refusal is what --verify says, not a missing log of a diff it should not have tried."""
    dpus.start(1)
    done = skel("allocate", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--dpus", "2", "--objective", "traffic",
                "--out", str(tmp_path / "pair.yaml"), "--verify", "--url", url, timeout=120)
    assert done.returncode == 1, done.stdout + done.stderr
    assert "pair-10ms-5ms.yaml did not run, exit 1:" in done.stdout, done.stdout
    assert "DPU 1 (pid" in done.stdout and "already up" in done.stdout, done.stdout
    assert "No such file" not in done.stdout + done.stderr and "B - A" not in done.stdout
