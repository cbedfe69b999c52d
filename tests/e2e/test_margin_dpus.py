"""`skel margin --measure` on real DPUs: one run of live pushes, nothing restarted."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import skel

import skeleton

HALF = """\
system: half
dpus: [{id: 1}]
processes:
  - {id: 1, name: a, dpu: 1, period_us: 10000, compute_us: 2000}
  - {id: 2, name: b, dpu: 1, period_us: 10000, compute_us: 3000}
run: {warmup_cycles: 10, stop_on: []}
"""


@pytest.mark.timing
def test_a_half_loaded_dpu_measures_a_margin_between_1_8_and_2_restarting_nothing(
        tmp_path: Path, url: str, state_dir: Path) -> None:
    path = tmp_path / "half.yaml"
    path.write_text(HALF)
    assert skel("up", str(path), "--url", url).returncode == 0
    try:
        pids = {d["dpu"]: d["pid"] for d in json.loads(skel("status", "--url", url, "--json").stdout)}
        out = tmp_path / "sweep"
        done = skel("margin", str(path), "--url", url, "--measure", "--dpu", "1", "--out", str(out), "--json")
        assert done.returncode == 0, done.stdout + done.stderr
        found = json.loads(done.stdout)
        assert found["margins"][0]["predicted"]["factor"] == pytest.approx(2.0, rel=1e-6)
        measured = found["margins"][0]["measured"]
        assert 1.8 <= measured["factor"] <= 2.0, measured
        # one log, every step a generation of its own, each with its window
        steps = [s["generation"] for s in measured["steps"]]
        assert len(steps) >= 2 and steps == list(range(steps[0], steps[0] + len(steps)))
        windows = [w.generation for w in skeleton.load_run(Path(measured["run"])).report.windows]
        assert windows == steps
        after = {d["dpu"]: d["pid"] for d in json.loads(skel("status", "--url", url, "--json").stdout)}
        assert after == pids  # nothing restarted
    finally:
        assert skel("down", "--url", url).returncode == 0
