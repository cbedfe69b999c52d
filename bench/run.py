"""`make bench`: skeleton against the bare tools, side by side in one run, as ratios.

(a) wake-up jitter: skel-dpu's release latency (the first process of each minor
    cycle: start - release) in `sleep` and `wall` compute modes, against cyclictest
    (Debian rt-tests) for the same time at the same period and scheduling class;
(b) publish cost: skel-dpu's comm_out per output buffer against a bare lcm_publish()
    loop in C (bench/lcm_publish.c) of the same message size at the same period (goal: at
    most 1.1x);
(c) the log reader against lcm.EventLog + the generated decoders (bench/logreader_bench.py;
    goal: at least 10x);
(d) compute emulation: per compute mode, one DPU alone computing 1200 and 3315 us per
    cycle: what each cycle reports against what was asked (goal: within 0.5 %);
(e) the tasking executive: one DPU in sleep mode runs a rate-monotonic set; each job's
    start and completion against the ideal schedule's (host/theory/schedule.py), aligned by
    release (goal: start p99 within 50 us over the jobs no stall of the machine touched:
    neither their own nor one of a job they were queued behind);
(f) skel allocate: seeded systems of 40 processes on 8 DPUs, per objective (goal: an
    answer within 30 s);
(g) floods (bench/flood.py): SERVO signed, while 100 000 hostile messages a second for 10 s
    go to its control and buffer channels, against the same run clean (goals: every message
    counted as refused, % compute per DPU within 2 points);
(h) bookkeeping and (i) cycle rate (bench/cost.py): what a process-cycle of no compute costs
    the executive and its record (goal: median 1 us), and at 1 to 10 kHz the DPU's overrun
    frames against cyclictest's wake-ups later than the frame's slack, side by side (goal: at
    most 1.2x at every rate), and the same measure of a bare frame of the same work
    (bench/frame.c);
(j) scale (bench/scale.py, root only): namespace hosts on one bridge, sizes from 64 to 512
    processes at 100 Hz until one past the goal is not clean (goal: 64 DPUs and 256 processes
    with no buffer dropped and no lockout); the largest clean size;
(k) analysis (bench/analysis.py): `skel report` and `skel export` of a SERVO run grown to 10^7
    records, each against a floor measured on the same log (goals: the report within 2x reading
    and sorting its timing columns once, in at most 1x the log's size; the export within 1.5x
    the plain mcap writer), and `skel watch`'s refresh at 10^6 records;
(l) simulate (bench/simulation.py): ten minutes of SERVO on virtual time (goal: 100 simulated
    seconds per wall second), and a handover between DPUs as a fiber switch against threads.

Each part writes bench/results/<name>.txt, the headlines go to bench/results/summary.txt.
Runs use a private multicast port with ttl=0 (nothing leaves the host). The whole of it has
BUDGET_S (goal: 15 minutes), said with PASS/FAIL on the summary's last line.

Usage: .venv/bin/python bench/run.py [--seconds S] [--records N] [--tasking-seconds S]
       [--allocate-seconds S] [--flood-rate N] [--analysis-records N] [--parts P,...]
       [--results DIR]
(--parts: only those of wakeup, publish, logreader, compute, tasking, allocate, flood, bookkeeping, rate,
scale, analysis, simulate;
summary.txt is then
left alone and the headlines are printed only.)
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import functools
import importlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any, TypeVar

import cost  # bench/cost.py, beside this file
import lcm
import numpy as np
from cost import us_at
from machine import Ticks, machine_line

import skelmsg
from skeleton.analysis.measure.metrics import cycle_end_ns, first_of_frame
from skeleton.analysis.read.logreader import read_log
from skeleton.analysis.read.parallel import one_heap
from skeleton.analysis.read.records import load_records
from skeleton.host.sysfile.system import loads
from skeleton.host.theory.schedule import ideal_schedule, response_times, utilization

T = TypeVar("T")
BENCH = Path(__file__).resolve().parent
REPO = BENCH.parent
RESULTS = BENCH / "results"
LCM_PREFIX = Path(lcm.__file__).resolve().parent.parent
PERIOD_US = 1000
BUFFER_BYTES = 1024
WARMUP_CYCLES = 200
URL = f"udpm://239.255.76.67:{7000 + os.getpid() % 500 * 2}?ttl=0"

SYSTEM = f"""\
system: bench
links: [{{name: bus, url: "{URL}"}}]
dpus: [{{id: 1, compute: sleep}}]
buffers: [{{id: 1, name: out, bytes: {BUFFER_BYTES}}}]
processes:
  - {{id: 1, name: cyclic, dpu: 1, period_us: {PERIOD_US}, compute_us: 100, outputs: [out]}}
run: {{warmup_cycles: {WARMUP_CYCLES}, lockout_cycles: 1000, stop_on: []}}
"""


COMPUTE_SYSTEM = f"""\
system: compute
links: [{{name: bus, url: "{URL}"}}]
dpus: [{{id: 1, compute: sleep}}]
processes:
  - {{id: 1, name: short, dpu: 1, period_us: 5000, compute_us: 1200}}
  - {{id: 2, name: long, dpu: 1, period_us: 5000, compute_us: 3315}}
run: {{warmup_cycles: 20, lockout_cycles: 1000, stop_on: []}}
"""


def skel_run(tmp: Path, mode: str, seconds: float, text: str = SYSTEM, name: str = "",
             warmup: int = WARMUP_CYCLES, flawed: tuple[int, ...] = (3,),
             more: tuple[str, ...] = ()) -> np.ndarray:
    """Records of one real run of `text` with the DPU in compute mode `mode`, in
    tmp/NAME+MODE, from cycle `warmup` on; `flawed`: the exit codes of a run that ran;
    `more`: further overrides (-s)."""
    system = tmp / "bench.yaml"
    system.write_text(text)
    out = tmp / f"{name}{mode}"
    argv = [sys.executable, "-m", "skeleton.host.cli", "run", str(system), "--spawn", "--url", URL,
            "--duration", str(seconds), "--out", str(out), "--json", "-s", f"dpu.1.compute={mode}"]
    for override in more:
        argv += ["-s", override]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=seconds + 60, cwd=REPO,
                          env={**os.environ, "SKEL_DPU": str(REPO / "build" / "skel-dpu")})
    if done.returncode not in (0, *flawed):
        raise SystemExit(f"bench: skel run ({mode}) failed:\n{done.stdout}{done.stderr}")
    records = load_records(read_log(out / "run.lcm")).records
    return records[records["cycle"] >= warmup]


def first_of_minor(records: np.ndarray) -> np.ndarray:
    """Release latency (ns) of the first process started in each minor cycle."""
    first = first_of_frame(records)
    return (records["start_ns"][first] - records["release_ns"][first]).astype(np.int64)


@functools.cache  # one install attempt per bench
def cyclictest_binary() -> tuple[str | None, str]:
    """cyclictest, installed from Debian's rt-tests when we are root; else why not."""
    found = shutil.which("cyclictest")
    if found:
        return found, ""
    if os.geteuid() != 0:
        return None, "cyclictest missing (Debian rt-tests) and not root: `sudo apt-get install rt-tests`"
    env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
    for cmd in (["apt-get", "update", "-qq"], ["apt-get", "install", "-y", "-qq", "rt-tests"]):
        if subprocess.run(cmd, capture_output=True, env=env).returncode != 0:
            return None, "cyclictest missing and `apt-get install rt-tests` failed"
    found = shutil.which("cyclictest")
    return (found, "") if found else (None, "rt-tests installed but no cyclictest on PATH")


@contextlib.contextmanager
def _timer_slack_1ns() -> Iterator[None]:
    """skel-dpu's executive sets its timer slack to 1 ns (prctl); cyclictest leaves the
    default 50 µs for SCHED_OTHER, which alone adds ~50 µs to every wake-up. A child's
    default slack is its parent's slack at fork (and setting a scheduling policy resets
    the slack to that default), so set ours around the fork, then restore it."""
    libc = ctypes.CDLL(None, use_errno=True)
    pr_set_timerslack = 29
    libc.prctl(pr_set_timerslack, 1, 0, 0, 0)
    try:
        yield
    finally:
        libc.prctl(pr_set_timerslack, 0, 0, 0, 0)  # 0: back to our default


def cyclictest_start(binary: str, seconds: float, priority: int, cpu: int,
                     period_us: int = PERIOD_US) -> subprocess.Popen[str]:  # fmt: skip
    """cyclictest for SECONDS on CPU, in the background: clock_nanosleep on an absolute time
    (as skel-dpu waits; cyclictest 2.x has no -n, it is the default), -m (locked memory),
    the same period, a histogram for the percentiles. It holds /dev/cpu_dma_latency at 0 (its
    default), as skel-dpu does for a run."""
    loops = int(seconds * 1e6 / period_us)
    argv = [binary, "-m", "-q", "-i", str(period_us), "-l", str(loops), "-h", "5000", "-a", str(cpu)]
    if priority:
        argv += ["-p", str(priority)]
    with _timer_slack_1ns():
        return subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def cyclictest_histogram(proc: subprocess.Popen[str], seconds: float) -> tuple[np.ndarray, float]:
    """The wake-ups of a cyclictest_start per whole µs of latency (the last bucket: 5000 µs or
    more), and the largest in µs."""
    out, err = proc.communicate(timeout=seconds + 30)
    if proc.returncode != 0:
        raise SystemExit(f"bench: cyclictest failed: {err.strip()}")
    counts = np.zeros(5001, dtype=np.int64)
    for line in out.splitlines():
        if re.fullmatch(r"\d+\s+\d+", line.strip()):
            bucket, count = map(int, line.split())
            counts[min(bucket, 5000)] += count
    overflow = re.search(r"# Histogram Overflows:\s*(\d+)", out)
    counts[5000] += int(overflow.group(1)) if overflow else 0
    worst = re.search(r"# Max Latencies:\s*(\d+)", out)
    if counts.sum() == 0:
        raise SystemExit(f"bench: no histogram from cyclictest:\n{out}{err}")
    return counts, float(worst.group(1)) if worst else float("nan")


def _fifo_priority(tmp: Path, mode: str) -> int:
    """The SCHED_FIFO priority the DPU of that run says it got (0: SCHED_OTHER)."""
    logs = "".join(f.read_text() for f in (tmp / mode / "logs").glob("*.log"))
    found = re.search(r"run \d+ started \(\d+ processes, SCHED_FIFO (\d+)\)", logs)
    return int(found.group(1)) if found else 0


# The DPU on CPU 0 and cyclictest on CPU 1, at the same time: on a shared virtual machine the
# hypervisor's spells (milliseconds, many a second) come and go, and two runs one after the
# other meet different ones. cyclictest runs a little longer: the DPU's run starts ~2 s late.
DPU_CPU, CYCLICTEST_CPU, CYCLICTEST_LEAD_S = 0, 1, 3.0
# skel-dpu's class for `sleep` cycles: SCHED_FIFO 10 where permitted (root), else SCHED_OTHER (0);
# cyclictest beside it runs in the same one
SLEEP_PRIORITY = 10 if os.geteuid() == 0 else 0


def with_cyclictest(work: Callable[[], T], seconds: float, priority: int,
                    period_us: int = PERIOD_US) -> tuple[T, tuple[np.ndarray, float] | None]:  # fmt: skip
    """work(), a DPU's run of SECONDS on DPU_CPU, with cyclictest at the same period and
    PRIORITY (0: SCHED_OTHER) on CYCLICTEST_CPU at the same time; cyclictest's histogram
    (cyclictest_histogram), None without cyclictest."""
    binary, _ = cyclictest_binary()
    lead = seconds + CYCLICTEST_LEAD_S
    ref = cyclictest_start(binary, lead, priority, CYCLICTEST_CPU, period_us) if binary else None
    try:
        done = work()
        return done, None if ref is None else cyclictest_histogram(ref, lead)
    finally:
        # The run failed or cyclictest hung: no SCHED_FIFO process left behind.
        if ref is not None and ref.poll() is None:
            ref.kill()
            ref.wait()


def part_wakeup(tmp: Path, seconds: float) -> list[str]:
    """Each mode against cyclictest in the same scheduling class, side by side: by default
    skel-dpu runs `sleep` cycles under SCHED_FIFO 10 where permitted, `wall` ones SCHED_OTHER."""
    why = cyclictest_binary()[1]
    lines = [f"# {seconds:.0f} s at {PERIOD_US} us per minor cycle, one DPU on CPU {DPU_CPU}, first "
             f"{WARMUP_CYCLES} cycles excluded; cyclictest -m -i {PERIOD_US} in the same class at the same "
             f"time on CPU {CYCLICTEST_CPU}"]
    heads, ratios = [], {}
    for mode in ("sleep", "wall"):
        priority = SLEEP_PRIORITY if mode == "sleep" else 0
        ns, histogram = with_cyclictest(
            lambda mode=mode: first_of_minor(skel_run(tmp, mode, seconds, more=(f"dpu.1.cpu={DPU_CPU}",))),
            seconds, priority)  # fmt: skip
        got = _fifo_priority(tmp, mode)
        klass = f"SCHED_FIFO {got}" if got else "SCHED_OTHER"
        lines.append(f"skel-dpu {mode} ({klass}): p50 {us_at(ns, 50):.1f} us, p99 {us_at(ns, 99):.1f} us, "
                     f"max {ns.max() / 1000:.1f} us ({len(ns)} minor cycles)")
        if histogram is None:
            heads.append(f"{mode} {us_at(ns, 99):.1f} us, cyclictest skipped: {why}")
            continue
        theirs = cost.cyclictest_result(*histogram)
        note = "" if got == priority else f" (NOT the DPU's class: it got {klass})"
        same = f"SCHED_FIFO {priority}" if priority else "SCHED_OTHER, timer slack 1 ns"
        lines.append(f"cyclictest ({same}{note}): p50 {theirs['p50']:.0f} us, p99 {theirs['p99']:.0f} us, "
                     f"max {theirs['max']:.0f} us ({theirs['samples']:.0f} wake-ups)")
        mine = us_at(ns, 99)
        ratio = ratios[mode] = mine / max(theirs["p99"], 1.0)  # cyclictest counts whole µs: never 0
        heads.append(f"{mode} {mine:.1f} us vs {theirs['p99']:.0f} us (ratio {ratio:.2f}; p50 "
                     f"{us_at(ns, 50):.1f} vs {theirs['p50']:.0f} us, {klass})")
    verdict = "" if "sleep" not in ratios else f": {'PASS' if ratios['sleep'] <= 1.2 else 'FAIL'} (sleep)"
    return [f"wake-up p99 (goal: ratio 1.2), skel vs cyclictest side by side: {'; '.join(heads)}{verdict}",
            *lines]


def build_c(name: str, *link: str) -> Path:
    """bench/NAME.c built into build/bench/NAME, as the DPU is built (warnings are errors)."""
    exe = REPO / "build" / "bench" / name
    exe.parent.mkdir(parents=True, exist_ok=True)
    argv = ["gcc", "-std=c11", "-D_GNU_SOURCE", "-O2", "-Wall", "-Wextra", "-Werror", "-o", str(exe),
            str(BENCH / f"{name}.c"), *link]
    done = subprocess.run(argv, capture_output=True, text=True)
    if done.returncode != 0:
        raise SystemExit(f"bench: cannot build {exe}:\n{done.stderr}")
    return exe


def part_publish(tmp: Path, seconds: float, records: np.ndarray | None) -> list[str]:
    """comm_out of the one-output process (one buffer_t per cycle) vs bare lcm_publish."""
    msg = skelmsg.buffer_t()
    msg.nbytes, msg.payload = BUFFER_BYTES, bytes(BUFFER_BYTES)
    size = len(msg.encode())
    exe = build_c("lcm_publish", f"-I{LCM_PREFIX / 'include'}", f"-L{LCM_PREFIX / 'lib'}",
                  f"-Wl,-rpath,{LCM_PREFIX / 'lib'}", "-llcm")
    count = int(seconds * 1e6 / PERIOD_US)
    # The same URL as the run's buffer, with the same listeners: none. On loopback a publish
    # delivers to every socket on its port, so each would cost the publisher; the run's
    # logger and host tool hear the record URL, and nothing reads the buffer.
    url = loads(SYSTEM, "bench.yaml").buffer_url("out")
    done = subprocess.run([str(exe), url, str(size), str(PERIOD_US), str(count)], capture_output=True,
                          text=True, timeout=seconds + 30)
    if done.returncode != 0:
        raise SystemExit(f"bench: lcm_publish failed: {done.stderr.strip()}")
    _, mean, p50, p99, worst = map(int, done.stdout.split())
    ours = records["comm_out_ns"] if records is not None else np.zeros(1)
    lines = [f"# one {BUFFER_BYTES}-byte buffer ({size} bytes encoded buffer_t) per {PERIOD_US} us cycle, "
             f"{len(ours)} cycles; bare: lcm_publish() of {size} bytes, {count} times, same period, "
             "same URL (the writer's own group and port) and listeners (none)",
             f"skel-dpu comm_out: mean {ours.mean() / 1000:.2f} us, p50 {us_at(ours, 50):.2f} us, "
             f"p99 {us_at(ours, 99):.2f} us, max {ours.max() / 1000:.1f} us",
             f"bare lcm_publish: mean {mean / 1000:.2f} us, p50 {p50 / 1000:.2f} us, "
             f"p99 {p99 / 1000:.2f} us, max {worst / 1000:.1f} us"]
    ratio = us_at(ours, 50) / max(p50 / 1000, 1e-3)
    head = (f"publish: skel {us_at(ours, 50):.2f} us, bare lcm {p50 / 1000:.2f} us (ratio {ratio:.2f}, "
            f"p50 per {size}-byte message; goal {PUBLISH_RATIO:g}): "
            f"{'PASS' if ratio <= PUBLISH_RATIO else 'FAIL'}")
    return [head, *lines]


def part_compute(tmp: Path, seconds: float) -> list[str]:
    """Per mode: the mean compute each cycle reports against what was asked."""
    asked = {1: 1200.0, 2: 3315.0}
    rows, worst = [], 0.0
    for mode in ("sleep", "wall", "cpu", "work"):
        recs = skel_run(tmp, mode, seconds, COMPUTE_SYSTEM, "compute-")
        errors = []
        for proc, want in asked.items():
            got = float(recs["compute_ns"][recs["process"] == proc].mean()) / 1000.0
            errors.append(100.0 * (got - want) / want)
        worst = max(worst, *map(abs, errors))
        rows.append(f"  {mode:5s}: 1200 us -> {asked[1] * (1 + errors[0] / 100):.1f} ({errors[0]:+.2f} %), "
                    f"3315 us -> {asked[2] * (1 + errors[1] / 100):.1f} ({errors[1]:+.2f} %)")
        if mode == "work":  # its iterations are fixed at start-up: it runs at the CPU's speed of the day
            dpu = json.loads((tmp / "compute-work" / "report.json").read_text())["dpus"][0]
            drift = dpu["work_drift_pct"]
            way = "slower" if drift > 0 else "faster"
            rows[-1] += (f"; the DPU measured its kernel {abs(drift):.2f} % {way} than at its start-up, "
                         "at the run's start or end (the larger)")
    verdict = "PASS" if worst <= 0.5 else "FAIL"
    return [f"compute emulation: worst error {worst:.2f} % of what was asked (goal 0.5 %): {verdict}", *rows]


# (compute, period) in µs, rate-monotonic: U = 0.695, a 50 ms hyperperiod, 4 preemptions in each,
# and on the ideal schedule no job ends within 1.75 ms of a release, so a few µs of the DPU's own
# work never decide a preemption the ideal schedule places elsewhere.
TASKING_SET = [(1750, 5000), (1250, 10000), (5500, 25000)]
TASKING_GOAL_US = 50.0
TASKING_SKIP_S = 0.5  # the start of the run: the first cycles of a fresh process
STALL_US = 50         # the DPU's stall threshold (dpu.h SKEL_STALL_NS): a job later than it was stalled


def tasking_system(tasks: list[tuple[int, int]]) -> str:
    lines = ["system: tasking-bench", f'links: [{{name: bus, url: "{URL}"}}]',
             "dpus: [{id: 1, compute: sleep, executive: threads}]", "processes:"]
    lines += [f"  - {{id: {i + 1}, name: p{i + 1}, dpu: 1, period_us: {t}, compute_us: {c}}}"
              for i, (c, t) in enumerate(tasks)]
    lines.append("run: {warmup_cycles: 0, lockout_cycles: 1000, stop_on: []}")
    return "\n".join(lines) + "\n"


def tasking_deviations(records: np.ndarray, tasks: list[tuple[int, int]]) -> dict[str, np.ndarray]:
    """Per job, measured - ideal (ns) of its start and completion, aligned by release: the
    run's t0 is where every process's cycle 0 was released, and each record's release is
    checked against the ideal's."""
    done = records[(records["flags"] & 0b1110) == 0]  # completed: not cut short, skipped, locked out
    period = np.array([t for _, t in tasks], dtype=np.int64)[done["process"] - 1] * 1000
    t0 = int(np.min(done["release_ns"] - done["cycle"] * period))
    horizon_us = int((done["release_ns"].max() - t0) // 1000) + 1
    ideal = ideal_schedule(tasks, horizon_us)
    keep = done["release_ns"] >= t0 + int(TASKING_SKIP_S * 1e9)
    start, end, dropped = [], [], 0
    for rec in done[keep]:
        job = ideal.get((int(rec["process"]) - 1, int(rec["cycle"])))
        if job is None or t0 + job.release * 1000 != rec["release_ns"]:
            dropped += 1
            continue
        start.append(int(rec["start_ns"]) - (t0 + job.start * 1000))
        t_end = int(rec["release_ns"]) + tasks[job.task][1] * 1000 - int(rec["slack_ns"])
        end.append(t_end - (t0 + job.completion * 1000))
    if dropped:
        raise SystemExit(f"bench: {dropped} tasking records match no ideal job by release")
    start_dev = np.array(start, dtype=np.int64)
    jobs = done[keep]
    return {"start": start_dev, "end": np.array(end),
            "stalled": stall_touched(jobs, jobs["start_ns"].astype(np.int64) - start_dev,
                                     [t for _, t in tasks])}


def stall_touched(done: np.ndarray, ideal_start_ns: np.ndarray, periods_us: list[int]) -> np.ndarray:
    """Per job of DONE (IDEAL_START_NS its ideal start), whether a stall touched it: its own
    record has one (a late wake-up, a gap), or a job at its priority or above (rate-monotonic:
    a period no longer, by PERIODS_US per process) that a stall touched was pending (release
    to end) while it waited, from its ideal start to its start. On one processor a job starts
    only when the jobs above it that are pending are done, so a 65 ms stall of the machine holds
    back every job queued behind it and, through them, those behind them; a stall of a job
    below it cannot, as that job is preempted."""
    period = np.asarray(periods_us, dtype=np.int64)[done["process"] - 1]
    release, start = done["release_ns"].astype(np.int64), done["start_ns"].astype(np.int64)
    end = cycle_end_ns(done).astype(np.int64)
    touched = done["stall_ns"] > 0
    while True:  # each pass carries a stall one job further down the queue
        before = touched.copy()
        for level in np.unique(period):
            above = touched & (period <= level)
            if not above.any():
                continue
            order = np.argsort(release[above], kind="stable")
            begin, finish = release[above][order], np.maximum.accumulate(end[above][order])
            mine = period == level
            # The latest end of those released before each job's start
            k = np.searchsorted(begin, start[mine], side="left")
            latest = np.where(k > 0, finish[np.maximum(k - 1, 0)], np.iinfo(np.int64).min)
            touched[mine] |= latest > ideal_start_ns[mine]
        if (touched == before).all():
            return touched


def part_tasking(tmp: Path, seconds: float) -> list[str]:
    """One tasking DPU in sleep mode against the ideal fixed-priority preemptive schedule, with
    the platform taken out: the deviation of the jobs no stall touched (the goal), and the share
    of jobs a stall touched beside the share of cyclictest's wake-ups (beside it, at the fastest
    task's period, in its class) later than the stall threshold."""
    tasks = TASKING_SET
    run, histogram = with_cyclictest(
        lambda: skel_run(tmp, "sleep", seconds, tasking_system(tasks), "tasking-", warmup=0), seconds,
        SLEEP_PRIORITY, min(t for _, t in tasks))
    dev = tasking_deviations(run, tasks)
    clean = ~dev["stalled"]
    start, end = np.abs(dev["start"][clean]), np.abs(dev["end"][clean])
    p99 = us_at(start, 99)
    verdict = "PASS" if p99 <= TASKING_GOAL_US else "FAIL"
    rta = [r / 1000 if r is not None else None for r in response_times(tasks)]
    spec = ", ".join(f"{c / 1000:g}/{t / 1000:g}" for c, t in tasks)
    late = dev["start"][clean]
    touched = float(dev["stalled"].mean())
    if histogram is None:
        probe = "no cyclictest beside it (Debian's rt-tests)"
    else:
        counts = histogram[0]
        probe = (f"cyclictest beside it woke later than the stall threshold ({STALL_US} us) in "
                 f"{counts[STALL_US:].sum() / counts.sum():.2%} of its wake-ups")
    return [
        f"tasking schedule (sleep, one DPU): jobs no stall touched start within p99 {p99:.1f} us of the "
        f"ideal schedule (goal {TASKING_GOAL_US:.0f} us): {verdict}; a stall touched {touched:.2%} of the "
        f"jobs, {probe}",
        f"# rate-monotonic C/T = {spec} ms (U = {float(utilization(tasks)):.3f}, exact RTA R = {rta} ms), "
        f"{seconds:.0f} s, jobs released in the first {TASKING_SKIP_S} s excluded; each job aligned with the "
        "ideal schedule's by its release (the run's t0 + k x T)",
        f"|start - ideal start| of the jobs no stall touched: p50 {us_at(start, 50):.1f} us, p99 "
        f"{p99:.1f} us, max {start.max() / 1000:.1f} us ({len(start)} of {len(clean)} jobs; signed: min "
        f"{late.min() / 1000:+.1f} us, mean {late.mean() / 1000:+.1f} us)",
        f"|completion - ideal completion| of those: p50 {us_at(end, 50):.1f} us, p99 "
        f"{us_at(end, 99):.1f} us, max {end.max() / 1000:.1f} us (the DPU's reading and writing of a job "
        "take the processor too)",
        f"jobs with a stall of the machine (a wake-up or gap over the stall threshold): "
        f"{int(dev['stalled'].sum())} of {len(clean)}",
    ]


def part_logreader(records: int) -> list[str]:
    sys.path.insert(0, str(BENCH))
    from logreader_bench import measure

    return measure(records)


def part_allocate(seconds: float) -> list[str]:
    """skel allocate on seeded pipelines of 40 processes and 8 DPUs, per objective (goal: an
    answer within 30 s, the solver's time limit being SECONDS)."""
    sys.path.insert(0, str(REPO / "tests"))
    from randsys import random_pipeline

    from skeleton.host.sysfile.system import loads
    from skeleton.host.theory.allocate import allocate
    from skeleton.host.theory.predict import predict

    rows, took = [], []
    for seed in (1, 2, 3):
        system = loads(random_pipeline(seed), REPO / f"pipeline-{seed}.yaml")
        for objective in ("load", "latency", "traffic"):
            start = time.monotonic()
            found = allocate(system, 8, objective, time_limit_s=seconds)
            took.append(time.monotonic() - start)
            rows.append(f"  seed {seed} {objective:8s} {took[-1]:6.2f} s  worst load "
                        f"{predict(system).worst_load_pct:.1f} -> {found.prediction.worst_load_pct:.1f} %  "
                        f"{'proven optimal' if found.optimal else 'best found'}, "
                        f"{found.candidates} candidate(s)")
    verdict = "PASS" if max(took) < 30 else "FAIL"
    return [f"allocate: 40 processes on 8 DPUs, slowest answer {max(took):.1f} s (goal 30 s, solver limit "
            f"{seconds:g} s): {verdict}", *rows]


def part_flood(tmp: Path, rate: int) -> list[str]:
    from flood import flood_servo, lines  # bench/flood.py, beside this file

    where = tmp / "flood"
    where.mkdir()
    return lines(flood_servo(where, URL, rate, FLOOD_SECONDS), rate, FLOOD_POINTS)


def cost_run(tmp: Path) -> Callable[[str, str, float], tuple[np.ndarray, dict[str, Any]]]:
    """bench/cost.py's runner: a sleep-mode run (SCHED_FIFO when permitted), its records
    past the warm-up and its report; one that overran or lost records (exit 1) ran too."""
    def run(text: str, name: str, seconds: float) -> tuple[np.ndarray, dict[str, Any]]:
        records = skel_run(tmp, "sleep", seconds, text, f"{name}-", flawed=(1, 3))
        return records, json.loads((tmp / f"{name}-sleep" / "report.json").read_text())
    return run


FLOOD_SECONDS = 10
FLOOD_POINTS = 2.0
PARTS = ("wakeup", "publish", "logreader", "compute", "tasking", "allocate", "flood", "bookkeeping", "rate",
         "scale", "analysis", "simulate")


def _beside(module: str) -> Any:
    """A part's module beside this file (bench/scale.py, analysis.py, simulation.py), imported
    only when its part runs."""
    return importlib.import_module(module)


PROBE_S = 2.0
PUBLISH_RATIO = 1.1  # a DPU's publish against a bare lcm_publish() of the same bytes
BUDGET_S = 15 * 60  # the whole of make bench (issue 46 item 5)


def probe_p99_us() -> float | None:
    """cyclictest's p99 over PROBE_S on the DPUs' CPU, in the sleep mode's class: what the
    machine's wake-ups were right after a part (None without cyclictest)."""
    binary, _ = cyclictest_binary()
    if binary is None:
        return None
    return cost.cyclictest_result(*cyclictest_histogram(
        cyclictest_start(binary, PROBE_S, SLEEP_PRIORITY, DPU_CPU), PROBE_S))["p99"]


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=5.0, help="length of each timed run (default 5)")
    parser.add_argument("--records", type=int, default=500_000, help="records in the reader's log")
    parser.add_argument("--tasking-seconds", type=float, default=15.0, help="length of the tasking run")
    parser.add_argument("--allocate-seconds", type=float, default=10.0, help="solver limit per allocation")
    parser.add_argument("--flood-rate", type=int, default=100_000, help="hostile messages a second")
    parser.add_argument("--analysis-records", type=int, default=10_000_000,
                        help="records of the grown run the analysis part reads and exports")
    parser.add_argument("--parts", default=",".join(PARTS), help=f"comma-separated, of {', '.join(PARTS)}")
    parser.add_argument("--results", type=Path, default=RESULTS,
                        help="where each part's figures go (default bench/results)")
    args = parser.parse_args()
    wanted = args.parts.split(",")
    if unknown := [p for p in wanted if p not in PARTS]:
        parser.error(f"unknown part(s) {', '.join(unknown)}: choose from {', '.join(PARTS)}")
    results = args.results
    results.mkdir(parents=True, exist_ok=True)
    one_heap()  # what it times in this process (the log reader, the MCAP writing) as `skel` runs it
    summary = [f"# make bench, {time.strftime('%Y-%m-%d %H:%M')}, {os.cpu_count()} CPUs, "
               f"load average {os.getloadavg()[0]:.1f} at start (the machine may be shared)"]
    parts: dict[str, list[str]] = {}
    began = time.monotonic()

    def run_part(name: str, work: Callable[[], list[str]]) -> None:
        """One part, with the machine it ran on beside its figures (bench/machine.py)."""
        before = Ticks.now()
        lines = work()
        after = Ticks.now()
        parts[name] = [*lines, machine_line(before, after, probe_p99_us())]

    with tempfile.TemporaryDirectory(prefix="skel-bench-") as name:
        tmp = Path(name)
        if "wakeup" in wanted or "publish" in wanted:  # publish reads the wake-up part's run
            run_part("wakeup", lambda: part_wakeup(tmp, args.seconds))
            if "wakeup" not in wanted:
                del parts["wakeup"]
        if "publish" in wanted:
            records = load_records(read_log(tmp / "sleep" / "run.lcm")).records
            run_part("publish", lambda: part_publish(tmp, args.seconds,
                                                     records[records["cycle"] >= WARMUP_CYCLES]))
        singles: dict[str, Callable[[], list[str]]] = {
            "logreader": lambda: part_logreader(args.records),
            "compute": lambda: part_compute(tmp, args.seconds),
            "tasking": lambda: part_tasking(tmp, args.tasking_seconds),
            "allocate": lambda: part_allocate(args.allocate_seconds),
            "flood": lambda: part_flood(tmp, args.flood_rate),
            "bookkeeping": lambda: cost.part_bookkeeping(cost_run(tmp), URL, args.seconds),
            "rate": lambda: cost.part_rate(cost_run(tmp), URL, with_cyclictest, build_c("frame"), DPU_CPU,
                                           SLEEP_PRIORITY),
            "scale": lambda: _beside("scale").part_scale(),
            "analysis": lambda: _beside("analysis").part_analysis(tmp, URL, args.analysis_records),
            "simulate": lambda: _beside("simulation").part_simulate(tmp),
        }
        for part, work in singles.items():
            if part in wanted:
                run_part(part, work)
    for name, lines in parts.items():
        (results / f"{name}.txt").write_text("\n".join(lines) + "\n")
        print("\n".join(lines) + "\n")
        summary.append(lines[0])
    took, goal = (time.monotonic() - began) / 60, BUDGET_S // 60
    if len(parts) == len(PARTS):
        summary.append(f"make bench: every part in {took:.1f} min (goal {goal} min): "
                       f"{'PASS' if took <= goal else 'FAIL'}")
        (results / "summary.txt").write_text("\n".join(summary) + "\n")
    else:
        summary.append(f"{', '.join(parts)}: {took:.1f} min (the {goal} min goal is for every part)")
    print("\n".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
