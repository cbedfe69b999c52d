"""tests/e2e/test_tasking.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import skel

from skeleton.host.theory.schedule import ideal_schedule, response_times

MS = 1000  # us

# C/T in ms, highest priority first (rate-monotonic). Chosen so that on the ideal schedule
# no job ends within 1 ms of a release or of its deadline: the DPU's own reading and
# writing of buffers (tens of us a job) delays each job a little, and must not decide a
# preemption or a deadline the theory places elsewhere.
SCHEDULABLE = [(3, 8), (3, 12), (7, 24)]    # U = 0.92; R = 3, 6, 22 ms


def _system(tmp_path: Path, tasks: list[tuple[int, int]], duration_s: float, compute: str = "sleep") -> Path:
    lines = ["system: tasking", f"dpus: [{{id: 1, executive: threads, compute: {compute}}}]", "processes:"]
    for i, (c, t) in enumerate(tasks):
        lines.append(f"  - {{id: {i + 1}, name: p{i + 1}, dpu: 1, period_us: {t * MS}, "
                     f"compute_us: {c * MS}}}")
    lines.append(f"run: {{duration_s: {duration_s}, warmup_cycles: 2, lockout_cycles: 1000, stop_on: []}}")
    path = tmp_path / "tasking.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


def test_a_task_of_zero_compute_responds_after_the_work_above_it() -> None:
    # a relay of no computation still waits for the higher priorities' work at the critical
    # instant, and for a release that comes at the instant it would run (p1's second, at 5)
    tasks = [(2, 5), (3, 10), (0, 20)]
    assert response_times(tasks) == [2, 5, 7]
    assert ideal_schedule(tasks, 20)[(2, 0)].completion == 7


BAD_PRIORITIES = [
    ("-s", "process.p1.priority=100", "processes.p1.priority"),
    ("-s", "process.p1.priority=0", "processes.p1.priority"),
    ("-s", "process.p1.priority=7", "processes.p2.priority: give every process of DPU 1 a priority"),
]


@pytest.mark.parametrize(("flag", "override", "says"), BAD_PRIORITIES)
def test_bad_priorities_are_one_line_exit_2(tmp_path: Path, flag: str, override: str, says: str) -> None:
    path = _system(tmp_path, SCHEDULABLE, 1)
    done = skel("check", str(path), flag, override)
    assert done.returncode == 2, done.stdout + done.stderr
    lines = done.stderr.strip().splitlines()
    assert len(lines) == 1 and str(path) in lines[0] and says in lines[0], done.stderr


def test_duplicate_and_cyclic_priorities_are_refused(tmp_path: Path) -> None:
    path = _system(tmp_path, SCHEDULABLE, 1)
    dup = skel("check", str(path), "-s", "process.p1.priority=5", "-s", "process.p2.priority=5",
               "-s", "process.p3.priority=4")
    taken = "processes.p2.priority: priority 5 is already taken on DPU 1 by 'p1'"
    assert dup.returncode == 2 and taken in dup.stderr, dup.stderr
    cyclic = skel("check", str(path), "-s", "dpu.1.executive=cyclic", "-s", "process.p1.priority=5")
    runs_by_order = "processes.p1.priority: DPU 1 runs the cyclic executive"
    assert cyclic.returncode == 2 and runs_by_order in cyclic.stderr, cyclic.stderr
    rate_monotonic = "p1 (priority 99), p2 (priority 98), p3 (priority 97)"
    for mode in ("sleep", "cpu", "wall", "work"):  # every mode runs on the tasking executive
        ok = skel("check", str(path), "-s", f"dpu.1.compute={mode}")
        assert ok.returncode == 0 and rate_monotonic in ok.stdout, ok.stdout
