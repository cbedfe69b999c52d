"""tests/e2e/test_host_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

import time
from pathlib import Path

from conftest import EXAMPLES, skel

PAIR = str(EXAMPLES / "pair-10ms-5ms.yaml")
# Light and patient (lockout after 1 s without a cycle), so a loaded test machine cannot fail it.
LAB_SYSTEM = """\
system: lab
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: state, bytes: 64}, {id: 2, name: command, bytes: 64}]
processes:
  - {id: 1, name: sensor, dpu: 1, period_us: 10000, compute_us: 300, outputs: [state]}
  - {id: 2, name: controller, dpu: 2, period_us: 10000, compute_us: 300, inputs: [state], outputs: [command]}
  - {id: 3, name: actuator, dpu: 1, period_us: 10000, compute_us: 300, inputs: [command]}
run: {warmup_cycles: 10, lockout_cycles: 100, stop_on: [jam]}
"""


def _lab(tmp_path: Path) -> str:
    path = tmp_path / "lab.yaml"
    path.write_text(LAB_SYSTEM)
    return str(path)


def test_no_dpu_within_wait_dpus_fails_clearly(tmp_path: Path, url: str) -> None:
    started = time.monotonic()
    done = skel("run", PAIR, "--url", url, "--wait-dpus", "0.5", "--out", str(tmp_path / "run"))
    assert done.returncode == 1, done.stdout + done.stderr
    assert "no heartbeat from DPU 1, 2" in done.stdout and "--wait-dpus" in done.stdout
    assert time.monotonic() - started < 30


def test_bad_options_are_one_line_exit_2(tmp_path: Path, url: str) -> None:
    for args in (("push", _lab(tmp_path), "--url", url, "--at-ms", "-5"),
                 ("clock", "--url", url, "--samples", "0"),
                 ("run", _lab(tmp_path), "--url", url, "--wait-dpus", "-1")):
        done = skel(*args)
        assert done.returncode == 2, (args, done.stdout, done.stderr)
        assert len(done.stderr.strip().splitlines()) == 1 and "Traceback" not in done.stderr, done.stderr
