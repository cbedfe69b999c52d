"""`make bench` parts that weigh the skeleton's own cost (bench/run.py runs them):

(h) bookkeeping: one DPU, 64 processes of zero compute and no buffers in one 1 ms minor
    cycle; what one process-cycle costs the executive and its timing record is the time
    from one process's start to the next one's (goals: median <= 1 us, p99 <= 5 us), and
    the run's own % overhead + % communicate (the time neither computing nor waiting) must
    account for what those costs and the frames' wake-ups add up to (within 1 point: a check
    that the report's columns hold that cost, not a second measure of it);
(i) cycle rate against the platform: one DPU, four processes of 10 us in one minor cycle,
    under SCHED_FIFO, at 1, 2, 5 and 10 kHz for 10 s each, with cyclictest at the same period
    and class beside it on the other CPU: the share of the DPU's frames that overran against
    the share of cyclictest's wake-ups later than the frame's slack, when woken that late any
    executive overruns (goal: at most 1.2 times at every rate: the executive adds nothing to
    what the platform takes; a VM's hypervisor stops it for up to 50 ms at times). The
    highest rate where the ratio holds, and the highest run clean, are printed. An overrun no
    stall explains is printed with the longest stretch its frame lost at once
    (frame_hiccups_ns): a platform's hiccup just under the stall threshold shows there. Then
    the bare frame (bench/frame.c: the same work after each wake-up, nothing else) on the
    same CPU, with cyclictest beside it again: what any executive of that frame meets by the
    same measure. A stall in the middle of a frame's work overruns it where cyclictest, whose
    frame holds no work, wakes on time, so the bare frame's ratio is the measure's own floor.
    Both print the share of frames that overran with no stall of their own CPU to explain it.

Each takes `run(text, name, seconds) -> (records, report)`: one real `skel run`.
"""

from __future__ import annotations

import functools
import itertools
import math
import subprocess
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from skeleton.analysis.measure.metrics import cycle_end_ns, stall_explains
from skeleton.analysis.read.records import FLAG_OVERRUN

Run = Callable[[str, str, float], tuple[np.ndarray, dict[str, Any]]]
# bench/run.py's with_cyclictest: (work, seconds, priority, period_us) -> (work(), its histogram)
Beside = Callable[[Callable[[], Any], float, int, int], tuple[Any, tuple[np.ndarray, float] | None]]

BOOK_PROCESSES = 64
BOOK_PERIOD_US = 1000
BOOK_GOAL_P50_US, BOOK_GOAL_P99_US, BOOK_AGREE_POINTS = 1.0, 5.0, 1.0
RATE_PROCESSES, RATE_COMPUTE_US = 4, 10
RATE_LADDER_HZ = (1000, 2000, 5000, 10000)
RATE_LADDER_S = 10.0
RATE_RATIO = 1.2


def system(name: str, url: str, processes: int, period_us: int, compute_us: int,
           cpu: int | None = None) -> str:  # fmt: skip
    pin = "" if cpu is None else f", cpu: {cpu}"
    lines = [f"system: {name}", f'links: [{{name: bus, url: "{url}"}}]',
             f"dpus: [{{id: 1, compute: sleep{pin}}}]", "processes:"]  # fmt: skip
    lines += [f"  - {{id: {i}, name: p{i}, dpu: 1, period_us: {period_us}, compute_us: {compute_us}}}"
              for i in range(1, processes + 1)]
    lines.append("run: {warmup_cycles: 200, lockout_cycles: 1000, stop_on: []}")
    return "\n".join(lines) + "\n"


def by_frame(records: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """One DPU's records in frame order (minor cycle, then start), whether each is its frame's
    first, and each one's start and end (ns)."""
    if len(np.unique(records["dpu"])) > 1:
        raise ValueError("by_frame: the records of one DPU")
    recs = records[np.lexsort((records["start_ns"], records["minor"]))]
    first = np.r_[True, recs["minor"][1:] != recs["minor"][:-1]][: len(recs)]
    return recs, first, recs["start_ns"].astype(np.int64), cycle_end_ns(recs).astype(np.int64)


def frame_costs_ns(records: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per minor cycle of one DPU's processes of no compute and no buffers: its wake-up (the first start
    less its release, or less the previous frame's end when that came later: a DPU behind runs
    on at once), the gaps from each process's start to the next one's (what a process-cycle
    costs, all of it) and the last process's own length."""
    recs, first, start, end = by_frame(records)
    last = np.r_[first[1:], True]
    gaps = (start[1:] - start[:-1])[~first[1:]]
    prev_end = np.r_[np.iinfo(np.int64).min, end[last][:-1]]
    wake = start[first] - np.maximum(recs["release_ns"][first].astype(np.int64), prev_end)
    return wake, gaps, end[last] - start[last]


def us_at(ns: np.ndarray, q: float) -> float:
    """The q-th percentile of nanoseconds, in µs (bench/run.py uses it too)."""
    return float(np.percentile(ns, q)) / 1000.0


def part_bookkeeping(run: Run, url: str, seconds: float) -> list[str]:
    text = system("bookkeeping", url, BOOK_PROCESSES, BOOK_PERIOD_US, 0)
    records, report = run(text, "bookkeeping", seconds)
    wake, gaps, tail = frame_costs_ns(records)
    p50, p99, mean = us_at(gaps, 50), us_at(gaps, 99), float(gaps.mean()) / 1000.0
    dpu = report["dpus"][0]
    # The run's time neither computing nor waiting, against what the wake-ups and the
    # process-cycles of its frames add up to
    busy = dpu["overhead_pct"] + dpu["communicate_pct"]
    expected = 100.0 * float(wake.sum() + gaps.sum() + tail.sum()) / (dpu["elapsed_ms"] * 1e6)
    ok = p50 <= BOOK_GOAL_P50_US and p99 <= BOOK_GOAL_P99_US and abs(busy - expected) <= BOOK_AGREE_POINTS
    return [
        f"bookkeeping: per process-cycle p50 {p50:.2f} us, p99 {p99:.2f} us (goals {BOOK_GOAL_P50_US:g} / "
        f"{BOOK_GOAL_P99_US:g} us); run's % overhead + % communicate {busy:.1f} vs {expected:.1f} "
        f"from that cost and the wake-ups (within {BOOK_AGREE_POINTS:g} point): {'PASS' if ok else 'FAIL'}",
        f"# {BOOK_PROCESSES} processes of 0 us and no buffers in one {BOOK_PERIOD_US} us minor cycle, "
        f"one DPU (sleep: SCHED_FIFO when permitted), {seconds:g} s; a process-cycle: one start to the next",
        f"per process-cycle: p50 {p50:.2f} us, mean {mean:.2f} us, p99 {p99:.2f} us, "
        f"max {gaps.max() / 1000:.1f} us ({len(gaps)} gaps)",
        f"wake-up per frame: p50 {us_at(wake, 50):.1f} us, mean {float(wake.mean()) / 1000:.1f} us",
        f"DPU 1: % compute {dpu['compute_pct']:.2f}, % communicate {dpu['communicate_pct']:.2f}, "
        f"% wait {dpu['wait_pct']:.2f}, % overhead {dpu['overhead_pct']:.2f} "
        f"(% stall {dpu['stall_pct']:.2f})",
    ]


def frame_hiccups_ns(records: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One DPU's records in frame order, whether each is its frame's first (by_frame) and, for
    each, the longest single stretch its frame lost at once: the frame's wake-up (first start
    less release), a process-cycle's length beyond what it was asked to compute, or a gap
    between two process-cycles."""
    recs, first, start, end = by_frame(records)
    if not len(recs):
        return recs, first, np.zeros(0, dtype=np.int64)
    frame = np.cumsum(first) - 1
    at = np.flatnonzero(first)
    wake = start[at] - recs["release_ns"][at].astype(np.int64)
    longer = end - start - recs["asked_ns"].astype(np.int64)
    gap = np.where(np.r_[first[1:], True], 0, np.r_[start[1:] - end[:-1], 0])
    worst = np.maximum(wake, np.maximum.reduceat(np.maximum(longer, gap), at))
    return recs, first, worst[frame]


def _clean(records: np.ndarray, report: dict[str, Any],
           unexplained: tuple[np.ndarray, np.ndarray, np.ndarray]) -> tuple[bool, str]:
    """Whether a rate's run was clean, and what it did (`unexplained`: unexplained_overruns of
    its records)."""
    overruns = sum(p["overruns"] for p in report["processes"])
    stalled = sum(p["overruns_stalled"] for p in report["processes"])
    lost = sum(b["to_seq"] - b["from_seq"] + 1 for b in report["integrity"]["lost_batches"])
    minors = len(np.unique(records["minor"]))
    late = records["start_ns"] - records["release_ns"]
    said = (f"{minors} minor cycles, {overruns} overruns ({stalled} of them the machine's stalls explain), "
            f"{lost} timing batches lost; release latency p50 {np.percentile(late, 50) / 1000:.1f} us, "
            f"p99 {np.percentile(late, 99) / 1000:.1f} us")
    # What the others lost: the stall threshold (SKEL_STALL_NS, dpu/dpu.h) is 50 us, and a
    # 10 kHz frame of 45 us has 55 us of slack, so a stretch of 40-50 us lost at once in a
    # frame is an overrun no stall explains, where a frame's usual stretches are a few us.
    recs, alone, hiccup = unexplained
    if overruns > stalled and alone.any():
        worst, usual = hiccup[alone] / 1000, np.percentile(hiccup, 50) / 1000
        span = f"{worst.min():.0f}" + (f"-{worst.max():.0f}" if worst.max() - worst.min() >= 1 else "")
        said += (f"; the {len(np.unique(recs['minor'][alone]))} frame(s) with an overrun no "
                 f"stall explains lost {span} us at once (a wake-up, a computation or a gap; a median "
                 f"frame {usual:.1f} us)")
    return overruns == stalled and lost == 0, said


def unexplained_overruns(records: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """One DPU's records in frame order, which overran with no stall to explain it, and each
    one's frame's longest stretch lost at once (frame_hiccups_ns)."""
    recs, first, hiccup = frame_hiccups_ns(records)
    return recs, ((recs["flags"] & FLAG_OVERRUN) != 0) & ~stall_explains(recs, first), hiccup


def _frames(records: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per minor cycle of one DPU: its work (the first start to the last end, ns) and whether
    any of its process-cycles overran."""
    recs, first, start, end = by_frame(records)
    at = np.flatnonzero(first)
    if not len(at):
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool)
    work = np.maximum.reduceat(end, at) - start[at]
    return work, np.logical_or.reduceat((recs["flags"] & FLAG_OVERRUN) != 0, at)


def cyclictest_result(counts: np.ndarray, worst: float) -> dict[str, float]:
    """p50/p99/max wake-up latency in µs of a cyclictest histogram (bench/run.py's
    cyclictest_histogram: wake-ups per whole µs)."""
    cumulative = np.cumsum(counts) / counts.sum()
    return {
        "p50": float(np.searchsorted(cumulative, 0.50)),
        "p99": float(np.searchsorted(cumulative, 0.99)),
        "max": worst,
        "samples": float(counts.sum()),
    }


def late_share(counts: np.ndarray, slack_us: float) -> float:
    """The share of cyclictest's wake-ups (a histogram per whole µs) at least SLACK_US late,
    rounded up to its whole µs."""
    return int(counts[max(0, math.ceil(slack_us)):].sum()) / counts.sum()


def machine_shares(records: np.ndarray, histogram: tuple[np.ndarray, float], minor_us: int) -> tuple[
        float, float, float]:
    """What the machine's own wake-ups leave a frame, against what the DPU's frames did: the share
    of cyclictest's wake-ups (at the same period beside the DPU) at least the frame's slack late
    (the minor cycle less the frame's median work), the share of the DPU's frames that overran,
    and that slack in µs."""
    work, overran = _frames(records)
    slack_us = minor_us - float(np.percentile(work, 50)) / 1000.0 if len(work) else float(minor_us)
    return late_share(histogram[0], slack_us), float(overran.mean()) if len(work) else 0.0, slack_us


def bare_frame(exe: Path, minor_us: int, cpu: int, priority: int) -> tuple[int, int, int]:
    """bench/frame.c (built as EXE) for RATE_LADDER_S: RATE_PROCESSES pieces of RATE_COMPUTE_US
    a frame at MINOR_US on CPU, SCHED_FIFO PRIORITY; its frames, how many overran and how many
    of those no stall explains."""
    argv = [str(exe), str(minor_us), str(RATE_COMPUTE_US), str(RATE_PROCESSES), f"{RATE_LADDER_S:g}",
            str(cpu), str(priority)]
    done = subprocess.run(argv, capture_output=True, text=True, timeout=RATE_LADDER_S + 30)
    if done.returncode != 0:
        raise SystemExit(f"bench: {exe.name} failed: {done.stderr.strip()}")
    frames, overran, unexplained = map(int, done.stdout.split())
    return frames, overran, unexplained


def share_ratio(ours: float, theirs: float) -> float:
    """The DPU's share of overrun frames over cyclictest's share of wake-ups that late: 1.0 when
    both are nil, infinite when only the DPU's is not."""
    if theirs > 0:
        return ours / theirs
    return 1.0 if ours == 0 else math.inf


def _up_to(rates: list[int]) -> str:
    """The highest rate of the ladder at which, and at every rate below it, RATES hold."""
    below = list(itertools.takewhile(lambda hz: hz in rates, RATE_LADDER_HZ))
    return f"{below[-1] / 1000:g} kHz" if below else "none"


def part_rate(run: Run, url: str, beside: Beside, frame: Path, cpu: int, priority: int) -> list[str]:
    """At each rate of RATE_LADDER_HZ, one DPU of RATE_PROCESSES processes of RATE_COMPUTE_US
    (on `cpu`) for RATE_LADDER_S with cyclictest at the same period and `priority` beside it
    (`beside`: bench/run.py's with_cyclictest): the share of the DPU's frames that overran
    against the share of cyclictest's wake-ups later than the frame's slack. Goal: at most
    RATE_RATIO times cyclictest's at every rate: the executive adds nothing to what the
    platform takes. Right after, the bare frame (`frame`: bench/frame.c built) of the same
    work on the same CPU in the same class, with cyclictest beside it again: what any
    executive of that frame meets, against the same measure."""
    lines, holds, clean_rates, bare_holds, bare_ratios = [], [], [], [], []
    alone_shares: list[tuple[float, float]] = []  # (the DPU's, the bare frame's) overruns no stall explains
    for hz in RATE_LADDER_HZ:
        minor_us = round(1e6 / hz)
        text = system("rate", url, RATE_PROCESSES, minor_us, RATE_COMPUTE_US, cpu)
        (records, report), histogram = beside(functools.partial(run, text, f"rate-{hz}", RATE_LADDER_S),
                                              RATE_LADDER_S, priority, minor_us)  # fmt: skip
        recs, unexplained, hiccup = unexplained_overruns(records)
        clean, said = _clean(records, report, (recs, unexplained, hiccup))
        if clean:
            clean_rates.append(hz)
        if histogram is None:
            lines.append(f"{hz / 1000:g} kHz: {said}; no cyclictest beside it (Debian's rt-tests)")
            continue
        theirs, ours, slack_us = machine_shares(records, histogram, minor_us)
        ratio = share_ratio(ours, theirs)
        if ratio <= RATE_RATIO:
            holds.append(hz)
        at = cyclictest_result(*histogram)
        lines.append(f"{hz / 1000:g} kHz: frames overran {ours:.2%}, cyclictest later than the frame's "
                     f"slack ({slack_us:.0f} us) {theirs:.2%}: ratio {ratio:.2f}; cyclictest p99 "
                     f"{at['p99']:.0f} us; {said}")
        work = functools.partial(bare_frame, frame, minor_us, cpu, priority)
        (frames, overran, alone), again = beside(work, RATE_LADDER_S, priority, minor_us)
        if again is None:
            continue
        bare_slack = minor_us - RATE_PROCESSES * RATE_COMPUTE_US
        bare, late = overran / frames, late_share(again[0], bare_slack)
        bare_ratios.append(share_ratio(bare, late))
        if bare_ratios[-1] <= RATE_RATIO:
            bare_holds.append(hz)
        ours_alone = len(np.unique(recs["minor"][unexplained])) / len(np.unique(recs["minor"]))
        alone_shares.append((ours_alone, alone / frames))
        lines.append(f"  the bare frame right after: overran {bare:.2%} ({overran} of {frames}), cyclictest "
                     f"beside it later than its slack ({bare_slack} us) {late:.2%}: ratio "
                     f"{bare_ratios[-1]:.2f}; the DPU's share over the bare frame's "
                     f"{share_ratio(ours, bare):.2f}; overruns no stall of their own CPU explains: the "
                     f"DPU's {ours_alone:.2%} of frames, the bare frame's {alone / frames:.2%}")
    klass = f"SCHED_FIFO {priority}" if priority else "SCHED_OTHER"
    verdict = "PASS" if len(holds) == len(RATE_LADDER_HZ) else "FAIL"
    best, clean_best = _up_to(holds), _up_to(clean_rates)
    bare_said = (f"; the bare frame of the same work against the same measure: ratios "
                 f"{', '.join(f'{r:.2f}' for r in bare_ratios)}, holds up to {_up_to(bare_holds)}; "
                 f"overruns no stall of their own CPU explains at most {max(a for a, _ in alone_shares):.2%} "
                 f"of the DPU's frames, {max(b for _, b in alone_shares):.2%} of the bare frame's"
                 if bare_ratios else "")
    return [f"cycle rate against the platform: the DPU's overrun frames at most {RATE_RATIO:g}x cyclictest's "
            f"late wake-ups at every rate of {', '.join(f'{h / 1000:g}' for h in RATE_LADDER_HZ)} kHz: "
            f"{verdict}; the ratio holds up to {best}, clean (no overrun) up to {clean_best}{bare_said}",
            f"# {RATE_PROCESSES} processes of {RATE_COMPUTE_US} us in one minor cycle, one DPU on CPU {cpu}, "
            f"{RATE_LADDER_S:g} s a rate, cyclictest at the same period beside it on the other CPU "
            f"({klass}); "
            f"then the bare frame (bench/frame.c: {RATE_PROCESSES} x {RATE_COMPUTE_US} us busy on the wall "
            "clock after each wake-up, nothing else) on the same CPU, class and period, cyclictest beside "
            "it again",
            *lines]
