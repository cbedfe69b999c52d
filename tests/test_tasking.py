"""The tasking executive (`executive: threads`, compute mode sleep) against scheduling theory:
a DPU is one processor under fixed-priority preemptive scheduling. Real DPUs run textbook
rate-monotonic task sets; exact response-time analysis and a simulation of the ideal
schedule (host/schedule.py) say what each job must do, and the timing records are held to it."""

from __future__ import annotations

import math
from pathlib import Path

import pandas as pd
import pytest
from conftest import skel

import skeleton
from skeleton.host.schedule import ideal_schedule, response_times

MS = 1000  # us

# C/T in ms, highest priority first (rate-monotonic). Chosen so that on the ideal schedule
# no job ends within 1 ms of a release or of its deadline: the DPU's own reading and
# writing of buffers (tens of us a job) delays each job a little, and must not decide a
# preemption or a deadline the theory places elsewhere.
SCHEDULABLE = [(3, 8), (3, 12), (7, 24)]    # U = 0.92; R = 3, 6, 22 ms
UNSCHEDULABLE = [(3, 8), (6, 20), (6, 24)]  # U = 0.93; R3 = 30 ms > T3 = 24 ms


def _system(tmp_path: Path, tasks: list[tuple[int, int]], duration_s: float) -> Path:
    lines = ["system: tasking", "dpus: [{id: 1, executive: threads}]", "processes:"]
    for i, (c, t) in enumerate(tasks):
        lines.append(f"  - {{id: {i + 1}, name: p{i + 1}, dpu: 1, period_us: {t * MS}, "
                     f"compute_us: {c * MS}}}")
    lines.append(f"run: {{duration_s: {duration_s}, warmup_cycles: 2, lockout_cycles: 1000, stop_on: []}}")
    path = tmp_path / "tasking.yaml"
    path.write_text("\n".join(lines) + "\n")
    return path


# Stalls this short (a VM's usual hiccups) cannot alone break the 200 us of the margin.
STALL_NS = 100_000


def _run(tmp_path: Path, url: str, tasks: list[tuple[int, int]]) -> pd.DataFrame:
    """The measured, completed cycles of a 3 s run, less those of any hyperperiod in which
    the machine stalled the DPU longer than STALL_NS, and of the next (a stall delays real
    time, not the schedule: it would add an overrun the design does not have). Columns as
    the timing table's, plus `task`."""
    out = tmp_path / "run"
    run = skel("run", str(_system(tmp_path, tasks, 3)), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    timing = skeleton.load_run(out).timing.to_pandas()
    timing = timing[timing.measured & timing.completed].copy()
    timing["task"] = timing.process - 1
    hyper = math.lcm(*(t for _, t in tasks)) * MS * 1000
    period_ns = timing.task.map(lambda i: tasks[i][1] * MS * 1000)
    epoch = (timing.release_ns - timing.cycle * period_ns).min()  # every task's release 0
    timing["hyper"] = (timing.release_ns - epoch) // hyper
    stalled = set(timing.hyper[timing.stall_ns > STALL_NS])
    # The work a stall delays may spill into the next hyperperiod.
    kept = timing[~timing.hyper.isin(stalled | {h + 1 for h in stalled})]
    assert len(kept) >= 0.5 * len(timing), f"the machine stalled in {len(stalled)} hyperperiods"
    return kept


def test_rate_monotonic_responses_match_exact_response_time_analysis(tmp_path: Path, url: str) -> None:
    rta = response_times(SCHEDULABLE)
    assert rta == [3, 6, 22]
    cycles = _run(tmp_path, url, SCHEDULABLE)
    for i, r in enumerate(rta):
        mine = cycles[cycles.task == i]
        assert len(mine) >= 100, mine
        assert r is not None
        worst = mine.response_us.max()
        assert abs(worst - r * MS) <= 0.05 * r * MS + 200, (f"p{i + 1}", worst, r * MS)
        assert not mine.overrun.any(), mine[mine.overrun]
    # Every job is preempted exactly as often as on the ideal schedule (the lowest-priority
    # one, by the others' releases; the others never).
    ideal = ideal_schedule(SCHEDULABLE, 4000)
    measured = {(i, k): n for i, k, n in zip(cycles.task, cycles.cycle, cycles.preemptions, strict=True)}
    assert measured == {key: ideal[key].preemptions for key in measured}, measured
    assert max(measured.values()) >= 2 and cycles.preempted_ns[cycles.task == 2].min() > 0


def test_an_unschedulable_set_misses_exactly_the_deadlines_analysis_predicts(tmp_path: Path,
                                                                            url: str) -> None:
    rta = response_times(UNSCHEDULABLE)
    r3 = rta[2]
    assert rta[:2] == [3, 12] and r3 is not None and r3 > UNSCHEDULABLE[2][1]  # p3 misses its deadline
    cycles = _run(tmp_path, url, UNSCHEDULABLE)
    ideal = ideal_schedule(UNSCHEDULABLE, 4000)
    predicted = {(i, k) for (i, k), job in ideal.items() if job.response > UNSCHEDULABLE[i][1]}
    measured = set(zip(cycles.task[cycles.overrun], cycles.cycle[cycles.overrun], strict=True))
    ran = set(zip(cycles.task, cycles.cycle, strict=True))
    assert measured == predicted & ran, (sorted(measured), sorted(predicted & ran))
    assert any(i == 2 for i, _ in measured)  # it did miss
    for (i, k), row in cycles.set_index(["task", "cycle"]).iterrows():
        r = ideal[(i, k)].response * MS
        assert abs(row.response_us - r) <= 0.05 * r + 200, (i, k, row)


BAD_PRIORITIES = [
    ("-s", "process.p1.priority=100", "processes.p1.priority"),
    ("-s", "process.p1.priority=0", "processes.p1.priority"),
    ("-s", "process.p1.priority=7", "processes.p2.priority: give every process of DPU 1 a priority"),
    ("-s", "dpu.1.compute=cpu", "dpus.1.executive: 'threads' with compute 'cpu'"),
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
    ok = skel("check", str(path))
    rate_monotonic = "p1 (priority 99), p2 (priority 98), p3 (priority 97)"
    assert ok.returncode == 0 and rate_monotonic in ok.stdout, ok.stdout
