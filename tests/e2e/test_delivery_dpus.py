"""tests/unit/test_delivery.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import faults_but_stalls, skel
from unit.test_delivery import BIG, _big_url, _system

from skeleton.analysis.measure.faults import recv_buf_needed
from skeleton.host.sysfile.link import rmem_max


@pytest.mark.timing  # judges overruns: tests/steal.py
def test_a_dpu_sizes_its_socket_for_a_large_buffer_and_it_arrives(tmp_path: Path, url: str) -> None:
    need = recv_buf_needed(BIG)
    limit = rmem_max()
    if limit is None or limit < need:
        pytest.skip(f"net.core.rmem_max={limit} < {need}: this machine cannot carry a 1 MB buffer "
                    "(`skel check` says so; see the next test)")
    system = _system(tmp_path, _big_url())
    out = tmp_path / "run"
    done = skel("run", str(system), "--spawn", "--url", url, "--duration", "2", "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    for dpu in (1, 2):  # both open the link: the writer's socket receives its own traffic too
        log = (out / "logs" / f"dpu{dpu}.log").read_text()
        assert f"socket receive buffer of {need} bytes asked (recv_buf_size)" in log, log
    report = json.loads((out / "report.json").read_text())
    assert faults_but_stalls(report) == [], report["faults"]
    reader = next(p for p in report["processes"] if p["name"] == "jacobian_transpose")
    assert reader["cycles"] > 50 and reader["inputs"][0]["new"] > 50, reader


def test_a_buffer_that_never_arrives_is_a_delivery_failure_not_a_lockout(tmp_path: Path, url: str) -> None:
    # 4 MiB in 65 datagrams into a socket that holds one: a message never arrives whole.
    # Publishing them takes the writer 3-11 ms on this machine when quiet, past 20 ms beside
    # the other suites: a 100 ms period keeps this test on delivery, not on the writer's overrun.
    system = _system(tmp_path, _big_url("&recv_buf_size=4096"), bytes_=4 * 1024 * 1024, period_us=100_000)
    out = tmp_path / "run"
    done = skel("run", str(system), "--spawn", "--url", url, "--duration", "2", "--out", str(out))
    # Said before the run, then found: a delivery failure (exit 1), not the design's lockout (exit 3).
    assert "WARN buffer joint_state" in done.stdout, done.stdout
    assert done.returncode == 1, done.stdout + done.stderr
    report = json.loads((out / "report.json").read_text())
    # A stall of this shared machine (a 4 MiB buffer, sanitizer DPUs) is the platform's, not this test's.
    faults = faults_but_stalls(report)
    assert [f["kind"] for f in faults] == ["delivery"], report["faults"]
    fault = faults[0]
    assert (fault["buffer"], fault["writer"], fault["process"]) == \
        ("joint_state", "joint_sensors", "jacobian_transpose")
    assert "sysctl -w net.core.rmem_max=" in fault["detail"], fault["detail"]
    shown = skel("report", str(out / "run.lcm"))
    assert "delivery" in shown.stdout and "joint_state" in shown.stdout, shown.stdout
