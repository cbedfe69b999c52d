"""`make bench` parts that weigh the skeleton's own cost (bench/run.py runs them):

(h) bookkeeping: one DPU, 64 processes of zero compute and no buffers in one 1 ms minor
    cycle; what one process-cycle costs the executive and its timing record is the time
    from one process's start to the next one's (goals: median <= 1 us, p99 <= 5 us), and
    the run's own % overhead + % communicate (the time neither computing nor waiting) must
    account for what those costs and the frames' wake-ups add up to (within 1 point: a check
    that the report's columns hold that cost, not a second measure of it);
(i) cycle rate: one DPU, four processes of 10 us in a 100 us minor cycle (10 kHz) under
    SCHED_FIFO for 10^5 cycles: no overrun but those the machine's stalls explain (this VM's
    hypervisor stops it for up to 50 ms at times: the DPU overruns until it has caught up),
    no lost timing batch; then shorter minor
    cycles down to the floor the system file allows, each for 2 s, or, when 10 kHz was not
    clean, longer ones up to 1 ms, each for 2 s: the highest rate run clean is printed.
    Beside the 10 kHz run (its executive pinned to one CPU), cyclictest at the same period
    on another: how often this machine's timer alone wakes later than the frame's slack. An
    overrun no stall explains is printed with the longest stretch its frame lost at once
    (frame_hiccups_ns): a platform's hiccup just under the stall threshold shows there.

Each takes `run(text, name, seconds) -> (records, report)`: one real `skel run`.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np

from skeleton.analysis.measure.metrics import cycle_end_ns, stall_explains
from skeleton.analysis.read.records import FLAG_OVERRUN
from skelmsg import contract

Run = Callable[[str, str, float], tuple[np.ndarray, dict[str, Any]]]
# bench/run.py's with_cyclictest: (work, seconds, priority, period_us) -> (work(), its histogram)
Beside = Callable[[Callable[[], Any], float, int, int], tuple[Any, tuple[np.ndarray, float] | None]]

BOOK_PROCESSES = 64
BOOK_PERIOD_US = 1000
BOOK_GOAL_P50_US, BOOK_GOAL_P99_US, BOOK_AGREE_POINTS = 1.0, 5.0, 1.0
RATE_PROCESSES, RATE_COMPUTE_US, RATE_MINOR_US, RATE_CYCLES = 4, 10, 100, 100_000
RATE_PROBE_S = 2.0
RATE_PROBES_US = (80, 67, 50, 40, 33, 25, 20)  # past a clean 10 kHz
RATE_FALLBACKS_US = (125, 167, 200, 250, 333, 500, 1000)  # short of it: where this machine is clean


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


def _clean(records: np.ndarray, report: dict[str, Any]) -> tuple[bool, str]:
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
    if overruns > stalled:
        recs, first, hiccup = frame_hiccups_ns(records)
        bare = ((recs["flags"] & FLAG_OVERRUN) != 0) & ~stall_explains(recs, first)
        if bare.any():
            worst, usual = hiccup[bare] / 1000, np.percentile(hiccup, 50) / 1000
            said += (f"; the {len(np.unique(recs['minor'][bare]))} frame(s) with an overrun no stall "
                     f"explains lost {worst.min():.0f}-{worst.max():.0f} us at once (a wake-up, a "
                     f"computation or a gap; a median frame {usual:.1f} us)")
    return overruns == stalled and lost == 0, said


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


def _machine_floor(records: np.ndarray, histogram: tuple[np.ndarray, float] | None, minor_us: int,
                   priority: int) -> tuple[str, list[str]]:  # fmt: skip
    """What the machine's own wake-ups leave a frame: the share of cyclictest's wake-ups (at the
    same period beside the DPU, at `priority`) at least the frame's slack late (the minor
    cycle less the frame's work, rounded up to cyclictest's whole µs), against the share of
    the DPU's frames that overran. (headline, lines)"""
    if histogram is None:
        return "", ["cyclictest beside it: skipped (no cyclictest: Debian's rt-tests)"]
    work, overran = _frames(records)
    if not len(work):
        return "", []
    counts = histogram[0]
    slack_us = minor_us - float(np.percentile(work, 50)) / 1000.0
    late = int(counts[max(0, math.ceil(slack_us)) :].sum())
    theirs, ours = late / counts.sum(), float(overran.mean())
    at = cyclictest_result(*histogram)
    klass = f"SCHED_FIFO {priority}" if priority else "SCHED_OTHER"
    return (f" (this machine's own wake-ups: cyclictest beside it woke later than the frame's slack in "
            f"{theirs:.2%} of its cycles; the DPU's frames overran in {ours:.2%})",
            [f"cyclictest beside it (the other CPU, the same period, {klass}): p50 {at['p50']:.0f} us, p99 "
             f"{at['p99']:.0f} us, max {at['max']:.0f} us; {late} of {counts.sum()} wake-ups ({theirs:.2%}) "
             f"later than the frame's slack of {slack_us:.0f} us (the minor cycle less the frame's work, "
             f"{minor_us - slack_us:.0f} us at the median): woken that late, any executive overruns. The "
             f"DPU's frames that overran: {int(overran.sum())} of {len(work)} ({ours:.2%})"])  # fmt: skip


def part_rate(run: Run, url: str, beside: Beside, cpu: int, priority: int) -> list[str]:
    """`beside(work, seconds, priority, period_us)`: work() with cyclictest at that period and
    priority beside it (bench/run.py's with_cyclictest: the DPU on DPU_CPU, passed here as
    `cpu`, and cyclictest on the other CPU)."""
    hz = 1e6 / RATE_MINOR_US
    seconds = RATE_CYCLES * RATE_MINOR_US / 1e6
    text = system("rate", url, RATE_PROCESSES, RATE_MINOR_US, RATE_COMPUTE_US, cpu)
    (records, report), histogram = beside(lambda: run(text, "rate", seconds), seconds, priority,
                                          RATE_MINOR_US)  # fmt: skip
    ok, said = _clean(records, report)
    floor, machine = _machine_floor(records, histogram, RATE_MINOR_US, priority)
    lines = [f"# {RATE_PROCESSES} processes of {RATE_COMPUTE_US} us in one minor cycle, one DPU on CPU {cpu} "
             f"(sleep mode: SCHED_FIFO when permitted); {RATE_MINOR_US} us for {seconds:g} s, then "
             f"{RATE_PROBE_S:g} s each: shorter down to the floor ({contract.MIN_PERIOD_US} us) when it was "
             f"clean, longer up to {RATE_FALLBACKS_US[-1]} us until one is when it was not",
             f"{RATE_MINOR_US} us ({hz / 1000:g} kHz): {said}", *machine]
    best = RATE_MINOR_US if ok else None
    # 2 s each is weaker evidence than the 10 s at 10 kHz: shorter ones until one is not clean,
    # or longer ones until one is
    for minor_us in (m for m in (RATE_PROBES_US if ok else RATE_FALLBACKS_US) if m >= contract.MIN_PERIOD_US):
        clean, said = _clean(*run(system("rate", url, RATE_PROCESSES, minor_us, RATE_COMPUTE_US, cpu),
                                  f"rate-{minor_us}", RATE_PROBE_S))
        lines.append(f"{minor_us} us ({1e3 / minor_us:.1f} kHz): {said}")
        if clean:
            best = minor_us
        if clean != ok:
            break
    top = f"{1e3 / best:.1f} kHz ({best} us)" if best else "none"
    return [f"cycle rate: {hz / 1000:g} kHz for {RATE_CYCLES} cycles {'clean' if ok else 'NOT clean'}; "
            f"highest clean rate {top}: {'PASS' if ok else 'FAIL'}{floor}", *lines]
