"""The tasking executive (`executive: threads`) against scheduling theory: a DPU is one
processor under fixed-priority preemptive scheduling. Real DPUs run textbook rate-monotonic
task sets; exact response-time analysis and a simulation of the ideal schedule
(host/theory/schedule.py) say what each job must do, and the timing records are held to it. In
compute mode sleep the DPU runs the schedule itself (exact); in cpu and wall the kernel does,
on SCHED_FIFO threads pinned to one CPU (within margins: the machine is shared)."""

from __future__ import annotations

import json
import math
import os
import shutil
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pandas as pd
import pytest
from conftest import ASAN_DPU, SANITIZER_ERROR, skel
from unit.test_schedule import MS, SCHEDULABLE, _system

import skeleton
from skeleton.host.theory.schedule import ideal_schedule, response_times

UNSCHEDULABLE = [(3, 8), (6, 20), (6, 24)]  # U = 0.93; R3 = 30 ms > T3 = 24 ms


# RUN_S seconds of a set on the real machine: thousands of jobs, so that the typical one says
# what the platform costs (the median), whatever stalls the hypervisor put into a few.
RUN_S = 8
# A job starts and completes no earlier than on the ideal schedule: the clock's reading and
# the record's rounding allow this much.
EARLY_NS = 20_000


def _margin_ms(response_ms: float) -> float:
    """How far a typical measured response may be from the ideal one: the DPU's own reading and
    writing of buffers, and the clock."""
    return 0.05 * response_ms + 0.2


def _run(tmp_path: Path, url: str, tasks: list[tuple[int, int]]) -> pd.DataFrame:
    """The measured, completed cycles of a RUN_S run on real time, each beside its job on the
    ideal schedule: columns as the timing table's, plus `task`, `early_start_ns` and
    `early_end_ns` (how much earlier than ideal it started and completed: <= 0 on any platform)
    and `late_ms` (how much later it completed)."""
    out = tmp_path / "run"
    run = skel("run", str(_system(tmp_path, tasks, RUN_S)), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    timing = skeleton.load_run(out).timing.to_pandas()
    timing = timing[timing.completed & timing.measured].copy()
    timing["task"] = timing.process - 1
    period_ns = timing.task.map(lambda i: tasks[i][1] * MS * 1000)
    epoch = (timing.release_ns - timing.cycle * period_ns).min()  # every task's release 0
    ideal = ideal_schedule(tasks, (RUN_S + 1) * 1000)
    jobs = [ideal[(i, k)] for i, k in zip(timing.task, timing.cycle, strict=True)]
    start_ns = pd.Series([epoch + job.start * MS * 1000 for job in jobs], index=timing.index)
    end_ns = pd.Series([epoch + job.completion * MS * 1000 for job in jobs], index=timing.index)
    timing["early_start_ns"] = start_ns - timing.start_ns
    timing["early_end_ns"] = end_ns - (timing.release_ns + timing.response_us * 1000)
    timing["late_ms"] = -timing.early_end_ns / 1e6
    timing["ideal_response_ms"] = [job.response for job in jobs]
    return timing


def _held_to_the_ideal_schedule(cycles: pd.DataFrame) -> None:
    """What the real platform cannot blur: no job is served earlier than the ideal schedule
    serves it (a priority inversion or an early release would be), and the typical job within
    the margin of it. A stall of the machine only delays; the exact schedule, job by job, is
    tests/sim's, on virtual time."""
    early = cycles[(cycles.early_start_ns > EARLY_NS) | (cycles.early_end_ns > EARLY_NS)]
    assert early.empty, early[["task", "cycle", "early_start_ns", "early_end_ns"]]
    for task, mine in cycles.groupby("task"):
        typical = mine.late_ms.median()
        assert typical <= _margin_ms(mine.ideal_response_ms.median()), (f"p{task + 1}", typical)


@pytest.mark.timing
def test_rate_monotonic_responses_match_exact_response_time_analysis(tmp_path: Path, url: str) -> None:
    rta = response_times(SCHEDULABLE)
    assert rta == [3, 6, 22]
    cycles = _run(tmp_path, url, SCHEDULABLE)
    _held_to_the_ideal_schedule(cycles)
    for i, r in enumerate(rta):
        mine = cycles[cycles.task == i]
        assert len(mine) >= 100, mine
        assert r is not None
        # the critical instant comes every hyperperiod: its worst response is reached
        assert mine.response_us.max() >= r * MS - EARLY_NS / 1000, (f"p{i + 1}", mine.response_us.max())


@pytest.mark.timing
def test_an_unschedulable_set_misses_exactly_the_deadlines_analysis_predicts(tmp_path: Path,
                                                                            url: str) -> None:
    rta = response_times(UNSCHEDULABLE)
    r3 = rta[2]
    assert rta[:2] == [3, 12] and r3 is not None and r3 > UNSCHEDULABLE[2][1]  # p3 misses its deadline
    cycles = _run(tmp_path, url, UNSCHEDULABLE)
    _held_to_the_ideal_schedule(cycles)
    ideal = ideal_schedule(UNSCHEDULABLE, (RUN_S + 1) * 1000)
    predicted = {(i, k) for (i, k), job in ideal.items() if job.response > UNSCHEDULABLE[i][1]}
    measured = set(zip(cycles.task[cycles.overrun], cycles.cycle[cycles.overrun], strict=True))
    ran = set(zip(cycles.task, cycles.cycle, strict=True))
    # no job is served earlier than ideal: every predicted miss is a measured one; the platform
    # can only add misses, and the typical job is within the margin (above)
    assert predicted & ran <= measured, sorted(predicted & ran - measured)
    assert any(i == 2 for i, _ in measured)  # it did miss


def test_the_dpus_own_elapsed_time_is_the_analysis_whatever_order_its_jobs_complete_in(
    tmp_path: Path, url: str
) -> None:
    """The DPU sums a job when it completes. Its window opens at 20 ms, where only p2 is
    released; p1's job released at 21 ms preempts it and completes first: the DPU's own
    measured time began there, 1 ms after the analysis's (the first release, not the first
    one summed)."""
    tasks = [(1, 3), (5, 10)]  # R = 1, 8 ms
    out = tmp_path / "run"
    run = skel("run", str(_system(tmp_path, tasks, 1.0)), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    analysis = skeleton.load_run(out)
    (own,) = [r for r in analysis.messages.reports if r.run_id == analysis.report.run_id]
    (dpu,) = analysis.report.dpus
    assert dpu.elapsed_ms is not None
    # The same records, summed by each: the same time to the clock's nanosecond.
    assert own.elapsed_ns / 1e6 == pytest.approx(dpu.elapsed_ms, abs=1e-3), (own.elapsed_ns, dpu)


# Kernel-scheduled: C/T in ms, rate-monotonic, U = 0.71 (well under the kernel's 95 % real-time
# throttle). On the ideal schedule p3 runs 4-8, 10-12 and 14-15 ms: preempted twice, done at
# R3 = 15 ms, 1 ms before the next release, so the DPU's own overheads cannot add a preemption.
THREADED = [(2, 8), (2, 12), (7, 24)]  # R = 2, 4, 15 ms


@pytest.fixture
def busy_neighbours() -> Iterator[None]:
    """Two SCHED_OTHER processes spinning for the whole test: both cores are busy, as on a
    shared machine. SCHED_FIFO threads must not notice them."""
    spin = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(2)]
    yield
    for proc in spin:
        proc.kill()
        proc.wait()


def _threaded_run(tmp_path: Path, url: str, compute: str) -> tuple[pd.DataFrame, Path]:
    """A 3 s run of THREADED on the kernel-scheduled executive: its measured, completed cycles
    (plus `task`) and its output directory."""
    out = tmp_path / "run"
    path = _system(tmp_path, THREADED, 3, compute)
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    log = (out / "logs" / "dpu1.log").read_text(errors="replace")
    assert not SANITIZER_ERROR.search(log.encode()), log
    assert run.returncode in (0, 1, 3), run.stdout + run.stderr
    timing = skeleton.load_run(out).timing.to_pandas()
    timing = timing[timing.measured & timing.completed].copy()
    timing["task"] = timing.process - 1
    return timing, out


@pytest.mark.timing
@pytest.mark.parametrize("compute", ["cpu", "wall"])
def test_fifo_threads_preempt_as_response_time_analysis_bounds(tmp_path: Path, url: str, compute: str,
                                                              busy_neighbours: None) -> None:
    rta = response_times(THREADED)
    assert rta == [2, 4, 15]
    r3 = 15
    cycles, out = _threaded_run(tmp_path, url, compute)
    log = (out / "logs" / "dpu1.log").read_text(errors="replace")
    if "not faithful" in log and os.geteuid() != 0:   # root is never refused: there, a failure
        pytest.skip(f"SCHED_FIFO or pinning refused on this machine: {log}")
    assert "SCHED_FIFO 97..99 on CPU" in log, log
    # The machine itself may stop the CPU (a VM's vCPU not running: the guest sees no switch).
    # Nothing of the DPU can delay p1, SCHED_FIFO 99 on its CPU, by 1 ms: where p1 started or
    # ended that late, the platform stalled, and real time went on, not the schedule. Those
    # hyperperiods and the next are left out, as _run leaves out stalls in sleep mode, and so is
    # a p3 job still running when p1 was late (its response window reached a stall).
    hyper = math.lcm(*(t for _, t in THREADED)) * MS * 1000
    epoch = (cycles.release_ns - cycles.cycle * cycles.task.map(lambda i: THREADED[i][1] * MS * 1000)).min()
    cycles["hyper"] = (cycles.release_ns - epoch) // hyper
    p1 = cycles[cycles.task == 0]
    late = p1.release_latency_us.gt(1 * MS) | (p1.response_us - p1.compute_ns / 1000).gt(1 * MS)
    stalled = set(p1.hyper[late]) | {h + 1 for h in p1.hyper[late]}
    kept = cycles[~cycles.hyper.isin(stalled)]
    assert len(kept) >= 0.5 * len(cycles), f"the machine stalled p1 in {len(stalled) // 2} hyperperiods"
    late_p1_ns = p1.release_ns[late].to_numpy()
    hp = cycles[cycles.task < 2]  # all of them: a kept p3 job's window may reach a left-out hyperperiod
    cycles = kept
    low, high = cycles[cycles.task == 2], cycles[cycles.task == 0]
    ends = low.release_ns + low.response_us * 1000
    low = low[[not ((late_p1_ns >= r) & (late_p1_ns < e)).any()
               for r, e in zip(low.release_ns, ends, strict=True)]]
    assert len(low) >= 50 and len(high) >= 150, cycles.groupby("task").size()
    # Every p3 job ran its own computation and every higher-priority one released after it that
    # got the processor before it finished: preemption happened (the kernel's), and it is counted.
    # One released before p3's end but woken after it (its release latency) did not delay p3.
    # The bound holds for the design: the time the machine stopped the CPU in the window (the
    # jobs' stall_ns: gaps in a computation without a switch of its thread) is not the design's.
    # Its width, 1.3 R + 2 ms, is the platform's, measured (2026-12-02, 5 runs in each mode beside
    # the harness's probe, tests/probe/probe.c): p3's worst, less stalls, was 15.3-19.0 ms and
    # p1's 2.2-3.0 ms (R = 15 and 2 ms); within this file's sleep-mode margin (5 % + 0.2 ms) they
    # failed in 9 and 8 runs of 10. The probe in the same runs woke up to 3.7-14.7 ms late, 12-141
    # times 1 ms or more: a stop of the machine across a switch of threads is in no stall_ns. The
    # exact check of the schedule is the simulated one; this one checks the kernel preempts.
    hp_release = hp.release_ns.to_numpy()
    hp_start = hp_release + (hp.release_latency_us * 1000).to_numpy()
    hp_compute = hp.compute_ns.to_numpy()
    hp_stall = hp.stall_ns.to_numpy()
    for row in low.itertuples():
        end = row.release_ns + row.response_us * 1000
        before = ((hp_release >= row.release_ns) & (hp_start < end))
        floor_ns = row.compute_ns + hp_compute[before].sum()
        assert row.response_us * 1000 >= floor_ns - 100_000, (row, floor_ns)
        stalled_us = (row.stall_ns + hp_stall[before].sum()) / 1000
        assert row.response_us - stalled_us <= 1.3 * r3 * MS + 2 * MS, (row.cycle, row.response_us,
                                                                         stalled_us)
        assert row.preemptions > 0 and row.preempted_ns > 0, row
    assert low.response_us.min() >= r3 * MS - 200, low.response_us.min()
    # The highest priority is never preempted (a rare switch of the machine's own is let pass).
    assert (high.preemptions > 0).mean() <= 0.01, high.preemptions.value_counts()
    assert low.preemptions.median() == 2, low.preemptions.value_counts()  # as on the ideal schedule
    assert high.response_us.max() <= 1.3 * 2 * MS + 2 * MS, high.response_us.max()  # R1 = 2 ms
    report = json.loads((out / "report.json").read_text())
    assert report["not_faithful"] == [], report["not_faithful"]


def test_refused_sched_fifo_says_once_the_run_is_not_faithful(tmp_path: Path, url: str,
                                                              monkeypatch: pytest.MonkeyPatch) -> None:
    """Without CAP_SYS_NICE (dropped with setpriv, as an unprivileged user runs it) the threads
    stay SCHED_OTHER: the run goes on, one warning says why, and the report says not faithful."""
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        pytest.skip("setpriv (util-linux) is needed to drop CAP_SYS_NICE")
    wrapper = tmp_path / "skel-dpu-no-nice"
    wrapper.write_text(f"#!/bin/sh\nexec {setpriv} --bounding-set -sys_nice --inh-caps -sys_nice "
                       f"{ASAN_DPU} \"$@\"\n")
    wrapper.chmod(0o755)
    monkeypatch.setenv("SKEL_DPU", str(wrapper))
    cycles, out = _threaded_run(tmp_path, url, "cpu")
    log = (out / "logs" / "dpu1.log").read_text(errors="replace")
    assert log.count("warning: the tasking executive's threads cannot run under SCHED_FIFO") == 1, log
    assert "NOT FAITHFUL" in log, log
    assert set(cycles.task) == {0, 1, 2}, cycles.groupby("task").size()  # it ran, unfaithfully
    report = json.loads((out / "report.json").read_text())
    assert report["not_faithful"] == [1], report["not_faithful"]
    shown = skel("report", str(out))
    assert "DPU 1 is not faithful" in shown.stdout, shown.stdout
