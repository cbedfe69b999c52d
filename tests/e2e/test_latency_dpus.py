"""tests/unit/test_latency.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import skel

# The servo's sensor-to-command path, lightly loaded so a shared 2-core machine never
# locks it out: the test is about latencies, not about the allocation.
LIGHT_SERVO = """
system: light-servo
dpus: [{id: 1}, {id: 2}, {id: 3}]
buffers:
  - {id: 1, name: joint_state, bytes: 160}
  - {id: 2, name: jt_torque, bytes: 64}
  - {id: 3, name: command, bytes: 64}
processes:
  - {id: 1, name: joint_sensors, dpu: 1, period_us: 10000, compute_us: 300, outputs: [joint_state]}
  - {id: 2, name: jacobian_transpose, dpu: 2, period_us: 10000, compute_us: 1000, sync: data,
     inputs: [joint_state], outputs: [jt_torque]}
  - {id: 3, name: executor, dpu: 3, period_us: 10000, compute_us: 1000, inputs: [jt_torque, joint_state],
     outputs: [command]}
run: {cycles: 200, warmup_cycles: 10, lockout_cycles: 50}
chains:
  - [joint_sensors, jacobian_transpose, executor]
"""


@pytest.mark.timing
def test_real_run_has_small_buffer_latencies_and_chain_samples(tmp_path: Path, url: str) -> None:
    system = tmp_path / "light.yaml"
    system.write_text(LIGHT_SERVO)
    out = tmp_path / "run"
    run = skel("run", str(system), "--spawn", "--url", url, "--out", str(out), "--all")
    assert run.returncode == 0, run.stdout + run.stderr
    report = json.loads((out / "report.json").read_text())
    buffers = {b["buffer"]: b for b in report["buffers"]}
    assert set(buffers) == {"joint_state", "jt_torque"}  # command has no reader
    for b in buffers.values():
        assert b["published"] > 100, b
        for r in b["readers"]:
            lat = r["latency_us"]
            # One machine, one clock: positive, and well below the 10 ms period but for single
            # samples: on this shared machine a preempted sender or receiver stretches one
            # (13 ms seen under load; the harness's probe meets stops of 10-15 ms about once a
            # minute). So p99 is bounded, not the largest (5 runs here, 2026-12-02: p99 at most
            # 99 us, the largest 1.8 ms).
            assert r["samples"] > 100, (b["buffer"], r)
            assert 0 < lat["p50"] <= lat["p99"] <= lat["max"], (b["buffer"], r)
            assert lat["p99"] < 10_000, (b["buffer"], r)
            assert r["lost"] == 0, (b["buffer"], r)  # ttl=0 on one host: nothing is lost
    (chain,) = report["chains"]
    assert chain["processes"] == ["joint_sensors", "jacobian_transpose", "executor"]
    assert chain["samples"] > 100, chain
    # At least the transport of two hops and jacobian_transpose's compute (1 ms), and
    # less than a few periods.
    assert 1_000 < chain["latency_us"]["p50"] < 50_000, chain
    assert "per chain" in run.stdout and "per buffer" in run.stdout
