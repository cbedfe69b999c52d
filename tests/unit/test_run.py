"""tests/e2e/test_run_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
from conftest import EXAMPLES, LOCKOUT_SYSTEM, skel

from skeleton.host.live.run import keep_off_dpu_cpus
from skeleton.host.sysfile.system import System, load


def test_bad_system_file_is_one_line_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(LOCKOUT_SYSTEM.replace("period_us: 5000", "period_us: -5000"))
    for command in ("check", "run", "push"):
        result = skel(command, str(path))
        assert result.returncode == 2, (command, result.stdout, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
        assert lines[0].startswith(f"{path}: processes.hungry_reader.period_us:"), lines[0]


def _affinity_after_keep_off(system: System) -> set[int]:
    """keep_off_dpu_cpus in a thread of its own: the affinity it sets is the calling thread's."""
    got: list[set[int]] = []
    worker = threading.Thread(target=lambda: got.append(keep_off_dpu_cpus(system)))
    worker.start()
    worker.join()
    return got[0]


def test_the_host_tool_keeps_off_the_cpus_its_dpus_are_pinned_to() -> None:
    """Under SCHED_OTHER a DPU waking on a CPU where `skel run`'s live analysis runs waits
    out the scheduler's slice (`make bench` part wakeup): the tool moves off the CPUs this
    host's DPUs are pinned to, when others are left; a DPU of another host pins nothing here."""
    allowed = os.sched_getaffinity(0)
    if len(allowed) < 2:
        pytest.skip("one CPU: nowhere else to go")
    first, last = min(allowed), max(allowed)
    pair = EXAMPLES / "pair-10ms-5ms.yaml"
    assert _affinity_after_keep_off(load(pair, [f"dpu.1.cpu={first}"])) == allowed - {first}
    assert _affinity_after_keep_off(load(pair, [f"dpu.1.cpu={first}", "dpu.1.host=elsewhere"])) == allowed
    assert _affinity_after_keep_off(load(pair)) == allowed
    if len(allowed) == 2:  # every CPU taken: the tool stays where it may run
        assert _affinity_after_keep_off(load(pair, [f"dpu.1.cpu={first}", f"dpu.2.cpu={last}"])) == allowed
    assert os.sched_getaffinity(0) == allowed
