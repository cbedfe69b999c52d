"""A live switch of a tasking DPU (compute mode sleep: the DPU's own one-processor schedule,
dpu/tasking.c) on simulated time, with exact expectations: a push committed during a run takes
effect at one point of the grid, and the jobs in progress there carry over (dpu/swap.c).
tests/e2e/test_tasking_reconfig.py keeps the same switches on kernel threads (compute mode
cpu, dpu/threads.c), which only the real platform runs.

The set: p1 (T = 10 ms, C = 3 ms) and p2 (T = 12 ms, C = 3 ms), a 2 ms grid and a 60 ms
hyperperiod. The push is for 841 ms, 1 ms into the hyperperiod that starts at 840 ms,
so the switch falls on its 2 ms point, AT = 842 ms, where p1's job released at 840 ms has 1 ms
left to compute and p2's, released at 840 ms too, waits for the processor: both carry over."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import pandas as pd
from sim.test_executives import _cycles, simulate

MS = 1_000_000
AT = 842 * MS
SYSTEM = """\
system: tasking-switch
dpus: [{id: 1, executive: threads}]
processes:
  - {id: 1, name: p1, dpu: 1, period_us: 10000, compute_us: 3000}
  - {id: 2, name: p2, dpu: 1, period_us: 12000, compute_us: 3000}
run: {duration_s: 2.5, warmup_cycles: 2, lockout_cycles: 20, stop_on: []}
"""


def _pushed(tmp_path: Path, after: str, before: str = SYSTEM) -> tuple[dict[str, Any], pd.DataFrame]:
    """A run of `before` into which `after` is pushed at 841 ms: its report, and every completed
    job, with its release, start and end from the run's first release."""
    old, new = tmp_path / "before.yaml", tmp_path / "after.yaml"
    old.write_text(before)
    new.write_text(after)
    out = tmp_path / "run"
    report = simulate(out, str(old), "--push", f"0.841:{new}")
    assert report["generations"] == [1, 2]
    cycles = _cycles(out)
    cycles["release"] = cycles.release_ns - cycles.release_ns.min()
    cycles["start"] = cycles.start_ns - cycles.release_ns.min()
    cycles["end"] = cycles.release + (cycles.response_us * 1000).round().astype("int64")
    return report, cycles


def _switch(tmp_path: Path, after: str, before: str = SYSTEM) -> pd.DataFrame:
    """_pushed's jobs of a run that must end clean (no lockout, nothing cut short or skipped)."""
    report, cycles = _pushed(tmp_path, after, before)
    assert report["faults"] == [], report["faults"]
    for _, mine in cycles.groupby("process"):  # none lost, none twice
        assert sorted(mine.cycle) == list(range(mine.cycle.min(), mine.cycle.max() + 1))
    # The switch: every job released before it is the old plan's, every one at or after it the new.
    assert ((cycles.generation == 2) == (cycles.release >= AT)).all()
    return cycles


def _job(cycles: pd.DataFrame, process: int, release_ms: float) -> pd.Series:
    (row,) = cycles[(cycles.process == process) & (cycles.release == int(release_ms * MS))].itertuples()
    return row


def test_a_compute_change_carries_the_jobs_in_progress(tmp_path: Path) -> None:
    longer = SYSTEM.replace("compute_us: 3000}\n  - {id: 2", "compute_us: 4000}\n  - {id: 2")
    cycles = _switch(tmp_path, longer)
    assert cycles[cycles.generation == 2].release.min() == 850 * MS  # no release on the 2 ms point
    # p1's job in progress computes what it asked, 3 ms, without a preemption (it keeps the
    # higher priority), and ends at 843 ms; p2's waited behind it and starts then.
    p1 = _job(cycles, 1, 840)
    assert (p1.generation, p1.asked_ns, p1.compute_ns, p1.preemptions) == (1, 3 * MS, 3 * MS, 0)
    assert p1.end == 843 * MS
    p2 = _job(cycles, 2, 840)
    assert (p2.generation, p2.start, p2.end) == (1, 843 * MS, 846 * MS)
    p1s = cycles[cycles.process == 1]
    assert (p1s[p1s.release < AT].asked_ns == 3 * MS).all()
    new = p1s[p1s.release > AT]
    assert len(new) > 100 and (new.asked_ns == 4 * MS).all() and (new.compute_ns == 4 * MS).all()


def test_a_priority_swap_changes_which_process_is_preempted(tmp_path: Path) -> None:
    """The simulation commits a push 1 ms before its instant, here at 840 ms, while p1's job
    computes until 843 ms: the COMMIT must wake the DPU's wait (it did not, and the switch came
    at that completion: p2's carried job ran after p1's, not before it)."""
    swapped = SYSTEM.replace("compute_us: 3000}\n  - {id: 2", "compute_us: 3000, priority: 10}\n  - {id: 2")
    swapped = swapped.replace("period_us: 12000, compute_us: 3000}", "period_us: 12000, compute_us: 3000, "
                              "priority: 20}")
    cycles = _switch(tmp_path, swapped)
    # p2's carried job has the processor first from the switch on: it preempts p1's, 1 ms short
    # of done, which ends after it (842 + 3 + 1 ms).
    p1, p2 = _job(cycles, 1, 840), _job(cycles, 2, 840)
    assert (p1.preemptions, p1.compute_ns, p1.end) == (1, 3 * MS, 846 * MS)
    assert (p2.start, p2.end, p2.preemptions) == (842 * MS, 845 * MS, 0)
    # Before: p1 (rate-monotonic: first) is never preempted, p2 is; a hyperperiod after the
    # switch, once the carried jobs are done, the other way round.
    early = cycles[cycles.release < AT - 2 * MS]
    late = cycles[cycles.release >= 900 * MS]
    assert (early[early.process == 1].preemptions == 0).all() and early[early.process == 2].preemptions.any()
    assert (late[late.process == 2].preemptions == 0).all() and late[late.process == 1].preemptions.any()


def test_a_switch_adds_and_removes_processes(tmp_path: Path) -> None:
    p2, p3 = "id: 2, name: p2, dpu: 1, period_us: 12000, compute_us: 3000", "id: 3, name: p3, dpu: 1, " \
        "period_us: 20000, compute_us: 5000"
    cycles = _switch(tmp_path, SYSTEM.replace(p2, p3))
    # p2 leaves (its job carried at the switch goes with it, as at a run's end: no record); p3
    # comes on its own period's grid since the run's start: its first point after the switch.
    p2, p3 = cycles[cycles.process == 2], cycles[cycles.process == 3]
    assert p2.release.max() == 828 * MS
    assert (p3.release.min(), p3.cycle.min()) == (860 * MS, 43)
    assert (p3.generation == 2).all() and (p3.asked_ns == 5 * MS).all()


def test_a_switch_lets_an_overloaded_dpu_catch_up(tmp_path: Path) -> None:
    """At 120 % load p2 falls ever further behind (a release owed every 60 ms). Its computation
    cut live to 80 % load, its owed releases run back to back, none lost, and it catches up."""
    over = SYSTEM.replace("compute_us: 3000}\n  - {id: 2", "compute_us: 6000}\n  - {id: 2")
    before = over.replace("period_us: 12000, compute_us: 3000", "period_us: 20000, compute_us: 12000")
    after = over.replace("period_us: 12000, compute_us: 3000", "period_us: 20000, compute_us: 4000")
    # The switch on the 10 ms grid's point at or after 841 ms: 850 ms (p1's release, none of p2's).
    _, cycles = _pushed(tmp_path, after, before)
    p2 = cycles[cycles.process == 2].sort_values("cycle")
    assert sorted(p2.cycle) == list(range(p2.cycle.min(), p2.cycle.max() + 1))
    assert (p2.release == p2.cycle * 20 * MS).all()  # its phase kept
    at = 850 * MS
    assert ((p2.generation == 2) == (p2.release >= at)).all()
    owed = p2[(p2.release < at) & (p2.start >= at)]
    assert len(owed) >= 5 and (owed.asked_ns.iloc[1:] == 4 * MS).all(), owed
    last = p2[p2.release > p2.release.max() - 500 * MS]
    assert (last.response_us <= 20_000).all(), last


def test_a_period_change_keeps_the_phase(tmp_path: Path) -> None:
    cycles = _switch(tmp_path, SYSTEM.replace("period_us: 12000", "period_us: 6000"))
    p2 = cycles[cycles.process == 2].sort_values("cycle")
    old, new = p2[p2.release < AT], p2[p2.release >= AT]
    assert (old.release == old.cycle * 12 * MS).all()
    # from the old grid's next point on (852 ms), one release per new period
    assert new.release.tolist() == [852 * MS + i * 6 * MS for i in range(len(new))]
    assert len(new) > 200
