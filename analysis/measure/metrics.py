"""THE metric definitions: the measurement window, per-DPU utilization and
per-process cycle statistics (per-buffer transport latency and loss: latency.py;
chain latency: chains.py; faults: faults.py).

Everything here takes record arrays (records.RECORD_DTYPE / INPUT_DTYPE) and the
window's System (skeleton.host.model, read from its config_t), never a file, so a
post-mortem report, a replay and a live view compute the same numbers with the same code.

The measurement window is one per DPU, shared by all its processes: it opens at
t0 + warmup_cycles x the DPU's longest period (t0: the run's first release), when
even the slowest process is past its warm-up, and every record released from then
on counts. A fast process's warm-up is therefore longer than warmup_cycles of its
own cycles; in exchange its sums and a slow process's cover the same time, so the
DPU's % compute is its configured load whatever the mix of periods. The DPU's own
report_t sums use the same window.

Three times per cycle, each its own measure:
- release latency = start - r_k (the process's release): cyclictest's figure for
  the first process of a minor cycle; a later one includes the ones before it;
- lateness = start - the schedule's start (r_k plus the configured compute of the
  processes before it in its minor cycle): what `late` and `too late` judge; less the
  stalls the DPU had not caught up on (debt_ns), the design's own (lateness_unstalled);
- the DPU's frame release latency: the first start of each minor cycle - its release.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import NamedTuple

import numpy as np

from skeleton.host.model import Process, System

from ..read.records import FLAG_OVERRUN, FLAG_RELEASE_SKIPPED, FLAG_SKIPPED
from .stats import Histogram, LatencyUs, distribution, group_slices
from .stats import latency_us as _latency


@dataclass
class InputMetrics:
    buffer: str
    buffer_id: int
    new: int  # completed cycles that found a newer sequence
    stale: int  # completed cycles that found nothing new (in_new == 0)
    dropped: int  # sequences skipped (writer faster than reader, or loss)
    received: int  # messages received


@dataclass
class EventMetrics:
    """A `sync: event` process's events over the measured window."""
    event: str
    handled: int  # completed cycles, one per event
    dropped: int  # events its full queue dropped (timing_t.event_dropped)
    queued_max: int  # the most events waiting behind one that started
    latency_us: LatencyUs  # event -> start
    response_us: LatencyUs  # event -> end of the cycle's work


@dataclass
class SlackUs:
    min: float | None
    mean: float | None


@dataclass
class ProcessMetrics:
    id: int
    name: str
    dpu: int
    period_us: int
    cycles: int  # completed cycles in the measured window (FLAG_SKIPPED excluded)
    skipped: int  # partial cycles (a run stopped during a data wait)
    overruns: int
    latency_us: LatencyUs  # release latency: start - release
    compute_mean_us: float | None
    slack_min_us: float | None
    late: int  # lateness > late_pct % of the period (includes the too-late ones)
    too_late: int  # lateness > too_late_pct % of the period
    first_overrun_cycle: int | None = None
    lateness_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))  # start - sched
    # lateness less the part the platform's stalls explain (timing_t.debt_ns), and the cycles
    # late by it: the design's lateness (the cyclic executive's; the others track no debt)
    lateness_unstalled_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))
    late_unstalled: int = 0
    releases_skipped: int = 0  # cycle skipping: a data-synchronised process a period behind
    # overruns that stalls explain (stall_explains): a DPU catching up after a 50 ms stall
    # overruns every cycle until it has
    overruns_stalled: int = 0
    stall_ms: float = 0.0  # time its cycles' thread was kept from running
    inputs: list[InputMetrics] = field(default_factory=list)
    response_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))  # end - release
    slack_us: SlackUs = field(default_factory=lambda: SlackUs(None, None))
    # A compute time that varies (process_t.nquantiles > 0): what the cycles were asked to
    # emulate (the draws) beside what they took, p50/p99/max and mean.
    varying: bool = False
    asked_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))
    asked_mean_us: float | None = None
    compute_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))
    events: EventMetrics | None = None  # sync: event processes only
    # "release_latency_us" and "response_us" (and an event process's "event_latency_us"):
    # HISTOGRAM_BINS equal bins each
    histograms: dict[str, Histogram] = field(default_factory=dict)


@dataclass
class DpuMetrics:
    id: int
    processes: list[str]
    configured_cycle_ms: float
    measured_cycle_ms: float | None
    compute_pct: float | None
    communicate_pct: float | None
    wait_pct: float | None
    overhead_pct: float | None  # 100 - the three others, so the four sum to 100
    static_load_pct: float
    overruns: int
    elapsed_ms: float | None
    records: int  # measured records
    # the first start of each minor cycle - its release (cyclictest's figure)
    release_latency_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))
    stall_ms: float = 0.0  # time the executive was kept from running (stalls) in the window
    stall_pct: float | None = None  # that time's share of elapsed_ms: what the platform took
    # % compute of the time the DPU would have taken had the platform not stalled it
    # (unstalled_ns): on a machine that never stalls, compute_pct; what the prediction, made
    # for a dedicated CPU, is held to.
    compute_unstalled_pct: float | None = None
    # release_latency_us less the stalls the DPU had not caught up on when each minor cycle
    # started (frame_release_latencies_ns): the executive's own wake-up latency.
    release_latency_unstalled_us: LatencyUs = field(default_factory=lambda: LatencyUs(None, None, None))


def per_id(ids: np.ndarray, values: dict[int, int]) -> np.ndarray:
    """values[id] for every element of `ids` (int16 ids of processes or DPUs), 0 when absent:
    one table lookup instead of a Python call per record."""
    table = np.zeros(1 << 16, dtype=np.int64)
    for key, value in values.items():
        table[int(key) & 0xFFFF] = value
    return table[ids.astype(np.int64) & 0xFFFF]


def window_start_ns(records: np.ndarray, system: System) -> dict[int, int]:
    """Per DPU with records: when its measurement window opens, on its own clock.

    t0 is where cycle 0 of every process was released (release - cycle x period of
    any record); the window opens warmup_cycles of the DPU's longest period later, where
    the DPU opens its own. A `sync: event` process's cycles count its events, not its
    periods: its records place t0 by their minor cycle instead (release - minor x minor
    cycle: exact on the cyclic executive, where such a cycle is released with its frame;
    at most one minor cycle late on the others, which release it when its event comes), so
    a DPU of events only opens its window when its run began, not at its first event."""
    longest: dict[int, int] = {}
    for p in system.processes:
        longest[p.dpu] = max(longest.get(p.dpu, 0), p.period_us * 1000)
    minor = {d.id: d.minor_cycle_us * 1000 for d in system.dpus}
    on_events = {p.id: p for p in system.processes if p.sync == "event"}
    step = per_id(records["process"], {p.id: minor.get(p.dpu, 0) if p.id in on_events else p.period_us * 1000
                                       for p in system.processes})  # fmt: skip
    count = np.where(per_id(records["process"], dict.fromkeys(on_events, 1)) == 1, records["minor"],
                     records["cycle"])  # fmt: skip
    t0 = records["release_ns"] - count * step
    return {dpu: first + system.run.warmup_cycles * longest.get(dpu, 0)
            for dpu, first in smallest_per_id(records["dpu"], t0).items()}


def smallest_per_id(ids: np.ndarray, values: np.ndarray) -> dict[int, int]:
    """id (a DPU's, a process's) -> the smallest of its `values`: one sort of the 16-bit ids,
    not a mask per id."""
    order, groups = group_slices(ids)
    ordered = values[order]
    return {d: int(ordered[rows].min()) for d, rows in groups.items()}


def measured(records: np.ndarray, system: System, starts: dict[int, int] | None = None) -> np.ndarray:
    """Mask of the records in their DPU's measurement window (`starts`: window_start_ns of
    these records or of a larger set holding them)."""
    if len(records) == 0:
        return np.zeros(0, dtype=bool)
    return records["release_ns"] >= per_id(records["dpu"], starts or window_start_ns(records, system))


def window_mask(records: np.ndarray, system: System, in_window: np.ndarray | None) -> np.ndarray:
    """`in_window` when the caller has it (window_part finds it once for every table of a
    window), else measured(records, system): a table called alone finds it itself."""
    return measured(records, system) if in_window is None else in_window


def rows_by_process(records: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, dict[int, slice]]:
    """The rows of `mask` grouped by process (each group in arrival order), and each
    process's slice of them: one sort instead of one full-array mask per process."""
    rows = np.flatnonzero(mask)
    order, groups = group_slices(records["process"][rows])
    return rows[order], groups


def completed(records: np.ndarray) -> np.ndarray:
    """Mask of the cycles that ran to the end: not partial, not a skipped release."""
    return (records["flags"] & (FLAG_SKIPPED | FLAG_RELEASE_SKIPPED)) == 0


def cycle_end_ns(records: np.ndarray) -> np.ndarray:
    """When a cycle's work ended: start + comm_in + blocked + preempted + compute + comm_out."""
    return (
        records["start_ns"]
        + records["comm_in_ns"]
        + records["blocked_ns"]
        + records["preempted_ns"]
        + records["compute_ns"]
        + records["comm_out_ns"]
    )


def static_load_pct(system: System, dpu_id: int, priority: int = 0) -> float:
    """Configured load of a DPU: 100 * sum(compute_us / period_us) of its processes (with
    `priority`: of those at that priority and above, on the tasking executive).

    Compute is divided by the DPU's speed factor, as the emulation divides it."""
    speed = next((d.speed for d in system.dpus if d.id == dpu_id), 1.0) or 1.0
    load = sum(p.compute_us / p.period_us for p in system.processes
               if p.dpu == dpu_id and p.period_us > 0 and p.priority >= priority)
    return 100.0 * load / speed


def dpu_metrics(records: np.ndarray, system: System, in_window: np.ndarray | None = None,
                earlier: Mapping[int, int] | None = None) -> list[DpuMetrics]:
    """Per DPU (by id) over the measured window (`in_window`: measured(records,
    system), when the caller has it); `earlier`: when each DPU's work of the generations
    before this one ended (windows.earlier_ends_ns), when there were any."""
    in_window = window_mask(records, system, in_window)
    window = records[in_window]
    warmup, earlier = warmup_end_ns(records[~in_window]), earlier or {}
    out = []
    for dpu in sorted(system.dpus, key=lambda d: d.id):
        procs = sorted((p for p in system.processes if p.dpu == dpu.id), key=lambda p: (p.order, p.id))
        mine = window[window["dpu"] == dpu.id]
        overruns = int(np.count_nonzero(overran(mine[completed(mine)])))
        elapsed = _elapsed_ns(mine, latest(warmup.get(dpu.id), earlier.get(dpu.id)))
        shares = utilization_pct(*shares_ns(mine), elapsed)
        stall = int(mine["stall_ns"].sum())
        given = unstalled_ns(mine, elapsed, stall, dpu.minor_cycle_us * 1000)
        latency, unstalled = frame_release_latencies_ns(mine)
        out.append(
            DpuMetrics(
                id=dpu.id,
                processes=[p.name for p in procs],
                configured_cycle_ms=dpu.minor_cycle_us / 1000.0,
                measured_cycle_ms=_measured_cycle_ms(mine),
                compute_pct=shares[0],
                communicate_pct=shares[1],
                wait_pct=shares[2],
                overhead_pct=shares[3],
                static_load_pct=static_load_pct(system, dpu.id),
                overruns=overruns,
                elapsed_ms=None if elapsed is None else elapsed / 1e6,
                records=len(mine),
                release_latency_us=_latency(latency.astype(np.float64) / 1000.0),
                stall_ms=stall / 1e6,
                stall_pct=100.0 * stall / elapsed if elapsed else None,
                compute_unstalled_pct=100.0 * int(mine["compute_ns"].sum()) / given if given else None,
                release_latency_unstalled_us=_latency(unstalled.astype(np.float64) / 1000.0),
            )
        )
    return out


class Frames(NamedTuple):
    """One DPU's minor cycles, in minor order."""

    minor: np.ndarray  # the minor cycle's index
    start: np.ndarray  # its first record's start
    release: np.ndarray  # its release


def frames(mine: np.ndarray) -> Frames:
    """The minor cycles of one DPU's records."""
    order, first = _minor_order(mine)
    if len(first) == 0:
        return Frames(*(np.zeros(0, dtype=np.int64) for _ in range(3)))
    minor, start, release = (_in(mine[c], order) for c in ("minor", "start_ns", "release_ns"))
    return Frames(minor[first], np.minimum.reduceat(start, first), np.minimum.reduceat(release, first))


def _minor_order(mine: np.ndarray) -> tuple[np.ndarray | None, np.ndarray]:
    """The order that puts one DPU's records in minor order (None: they are in it), and where
    each minor cycle's records begin in that order."""
    minor = mine["minor"]
    # A cyclic DPU's records come in minor order: seeing so takes one pass, and no sort or
    # gather is needed (three calls per DPU; each, over 10^7 records, 0.20 s instead of 0.31 s,
    # best of five). A tasking DPU's long job can end after a later minor cycle's.
    order = None
    if np.any(minor[1:] < minor[:-1]):
        order = np.argsort(minor, kind="stable")
        minor = minor[order]
    return order, np.flatnonzero(np.r_[len(minor) > 0, minor[1:] != minor[:-1]])


def _in(column: np.ndarray, order: np.ndarray | None) -> np.ndarray:
    return column if order is None else column[order]


def frame_release_latencies_ns(mine: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per minor cycle of one DPU's records: its first start - its release, and that less the
    stalls its DPU had not caught up on when that first record started (its debt_ns), as
    unstalled_lateness_us: a DPU behind after a stall starts its frames late by that debt, the
    platform's time, not its wake-up's. An early start stays. One pass for both: over 10^7
    records each takes about half a second."""
    order, first = _minor_order(mine)
    if len(first) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros(0, dtype=np.int64)
    start, release, debt = (_in(mine[c], order) for c in ("start_ns", "release_ns", "debt_ns"))
    earliest = np.minimum.reduceat(start, first)
    latency = earliest - np.minimum.reduceat(release, first)
    at = first
    if not np.array_equal(start[first], earliest):  # some minor cycle's first record started later
        frame = np.repeat(np.arange(len(first)), np.diff(np.r_[first, len(start)]))
        rows = np.flatnonzero(start == earliest[frame])
        at = rows[np.r_[True, frame[rows][1:] != frame[rows][:-1]]]
    return latency, np.where(latency > 0, np.maximum(latency - debt[at].astype(np.int64), 0), latency)


def _elapsed_ns(mine: np.ndarray, warmup_end: int | None) -> int | None:
    """One DPU's measured time (its measured records, `warmup_end`: when its work before them
    ended, warmup_end_ns of its others and of its earlier generations')."""
    if len(mine) == 0:
        return None
    return elapsed_ns(int(mine["release_ns"].min()), int(mine["start_ns"].min()),
                      int(work_end_ns(mine).max()), warmup_end)


def elapsed_ns(first_release: int, first_start: int, last_end: int, warmup_end: int | None) -> int:
    """What the DPU's shares divide: from its first measured release to the end of its last
    measured work plus its idle. A DPU behind its schedule is still working on warm-up cycles
    at that release, time no share counts (an overloaded one read 88 % compute where it
    computed 99 % of its time): its measured time begins when that work ended, and no later
    than its first measured start (a preempted warm-up cycle may end after it). A live switch
    is the same: a generation's window begins when the DPU's work of the one before ended
    (`warmup_end`: the later of the two)."""
    begin = first_release
    if warmup_end is not None and warmup_end > first_release:
        begin = min(warmup_end, first_start)
    return last_end - begin


def warmup_end_ns(before: np.ndarray) -> dict[int, int]:
    """Per DPU of `before`, cycles that ran before a window (its warm-up, or an earlier
    generation's), when their work ended: their completed ones, as the DPU's own sums see (a
    skipped release's record is stamped when its data came). DPUs without one: absent."""
    none = np.iinfo(np.int64).min
    order, groups = group_slices(before["dpu"])
    # Over the columns, not a copy of the rows: an earlier generation may hold millions.
    end = np.where(completed(before), cycle_end_ns(before), none)[order]
    ends = {d: int(end[rows].max()) for d, rows in groups.items()}
    return {d: e for d, e in ends.items() if e != none}


def latest(*times: int | None) -> int | None:
    """The latest of `times` that are known (None: none is)."""
    return max((t for t in times if t is not None), default=None)


def work_end_ns(records: np.ndarray) -> np.ndarray:
    """When each cycle's time on its DPU ended: the end of its work plus its idle."""
    return cycle_end_ns(records) + records["idle_ns"]


def unstalled_ns(mine: np.ndarray, elapsed: int | None, stall: int, minor_ns: int) -> int | None:
    """How long one DPU's measured records would have taken had the platform not stalled it:
    the elapsed time less the stalls, but never less than the schedule of the frames it ran
    (a stall that its idle time absorbed did not lengthen the run; an overloaded DPU falls
    behind by itself) nor more than it took."""
    if elapsed is None or elapsed <= 0:
        return None
    scheduled = int(mine["release_ns"].max() - mine["release_ns"].min()) + minor_ns
    return min(elapsed, max(elapsed - stall, scheduled))


def shares_ns(mine: np.ndarray) -> tuple[int, int, int]:
    """One DPU's measured (compute, communicate, wait) time: the sums utilization_pct divides.
    Partial (skipped) cycles count: the DPU really spent that time."""
    return (
        int(mine["compute_ns"].sum()),
        int(mine["comm_in_ns"].sum() + mine["comm_out_ns"].sum()),
        int(mine["blocked_ns"].sum() + mine["idle_ns"].sum()),
    )


def utilization_pct(
    compute_ns: int, communicate_ns: int, wait_ns: int, elapsed_ns: int | None
) -> tuple[float | None, float | None, float | None, float | None]:
    """The paper's Table 1 figures from a DPU's sums: (% compute, % communicate, % wait,
    % overhead), overhead being the remainder so the four sum to 100. Also used on the
    DPUs' own report_t totals when no log is at hand."""
    if elapsed_ns is None or elapsed_ns <= 0:
        return None, None, None, None
    compute = 100.0 * compute_ns / elapsed_ns
    communicate = 100.0 * communicate_ns / elapsed_ns
    wait = 100.0 * wait_ns / elapsed_ns
    return compute, communicate, wait, 100.0 - compute - communicate - wait


def _measured_cycle_ms(mine: np.ndarray) -> float | None:
    """Mean interval between consecutive minor-cycle starts (earliest start per minor index)."""
    starts = frames(mine).start
    if len(starts) < 2:
        return None
    return float(starts[-1] - starts[0]) / (len(starts) - 1) / 1e6


def overran(records: np.ndarray) -> np.ndarray:
    """Mask of the cycles that overran: flagged by the DPU, or ended past their deadline."""
    return ((records["flags"] & FLAG_OVERRUN) != 0) | (records["slack_ns"] < 0)


def process_metrics(
    records: np.ndarray, inputs: np.ndarray, system: System, in_window: np.ndarray | None = None,
    pairs: InputPairs | None = None,
) -> list[ProcessMetrics]:
    """Per process (by id) over the measured window (`in_window`: measured(records,
    system), when the caller has it) and `inputs`, the input records of `records` (`pairs`: their
    input_pairs, when the caller has them)."""
    in_window = window_mask(records, system, in_window)
    pairs = input_pairs(records, inputs, system, in_window) if pairs is None else pairs
    input_sums = _input_sums(inputs, pairs)
    at, by_process = rows_by_process(records, in_window)  # indexed, not copied, until one process's are taken
    # Whether a cycle was its frame's first matters only for the overruns (what the stalls explain).
    over = np.flatnonzero(in_window & completed(records) & overran(records))
    firsts = np.zeros(len(records), dtype=bool)
    firsts[over] = first_of_frame_at(records, over)
    out = []
    for proc in sorted(system.processes, key=lambda p: p.id):
        rows = at[by_process.get(int(proc.id), slice(0, 0))]
        mine = records[rows]
        skipped = (mine["flags"] & FLAG_SKIPPED) != 0
        ran = completed(mine)
        done = mine[ran]
        done_first = firsts[rows][ran]
        latency, latency_histogram = distribution(release_latency_us(done))
        lateness = lateness_us(done)
        unstalled = unstalled_lateness_us(done, lateness)
        response_ns = cycle_end_ns(done) - done["release_ns"]
        response, response_histogram = distribution(response_ns.astype(np.float64) / 1000.0)
        events, event_histogram = _events(proc, mine, done)
        did_overrun = overran(done)
        late_us, too_late_us = late_limits_us(proc, system)
        out.append(
            ProcessMetrics(
                id=proc.id,
                name=proc.name,
                dpu=proc.dpu,
                period_us=proc.period_us,
                cycles=len(done),
                skipped=int(np.count_nonzero(skipped)),
                overruns=int(np.count_nonzero(did_overrun)),
                latency_us=latency,
                compute_mean_us=float(done["compute_ns"].mean()) / 1000.0 if len(done) else None,
                slack_min_us=float(done["slack_ns"].min()) / 1000.0 if len(done) else None,
                late=int(np.count_nonzero(lateness > late_us)),
                too_late=int(np.count_nonzero(lateness > too_late_us)),
                first_overrun_cycle=int(done["cycle"][did_overrun].min()) if did_overrun.any() else None,
                inputs=[_input(input_sums.get((int(proc.id), int(b)), _NO_INPUTS), b, system)
                        for b in proc.inputs],
                response_us=response,
                slack_us=SlackUs(
                    float(done["slack_ns"].min()) / 1000.0 if len(done) else None,
                    float(done["slack_ns"].mean()) / 1000.0 if len(done) else None,
                ),
                histograms={"release_latency_us": latency_histogram, "response_us": response_histogram},
                lateness_us=_latency(lateness),
                lateness_unstalled_us=_latency(unstalled),
                late_unstalled=int(np.count_nonzero(unstalled > late_us)),
                releases_skipped=int(np.count_nonzero((mine["flags"] & FLAG_RELEASE_SKIPPED) != 0)),
                overruns_stalled=int(np.count_nonzero(did_overrun & stall_explains(done, done_first))),
                stall_ms=float(mine["stall_ns"].sum()) / 1e6,
                varying=proc.varying is not None,
                asked_us=_latency(done["asked_ns"].astype(np.float64) / 1000.0),
                asked_mean_us=float(done["asked_ns"].mean()) / 1000.0 if len(done) else None,
                compute_us=_latency(done["compute_ns"].astype(np.float64) / 1000.0),
                events=events,
            )
        )
        if event_histogram is not None:
            out[-1].histograms["event_latency_us"] = event_histogram
    return out


def release_latency_us(records: np.ndarray) -> np.ndarray:
    """start - release of each record, in µs."""
    return (records["start_ns"] - records["release_ns"]).astype(np.float64) / 1000.0


def lateness_us(records: np.ndarray) -> np.ndarray:
    """start - the schedule's start of each record, in µs."""
    return (records["start_ns"] - records["sched_ns"]).astype(np.float64) / 1000.0


def late_limits_us(proc: Process, system: System) -> tuple[float, float]:
    """The lateness (µs) beyond which a cycle of `proc` is late, and too late."""
    return proc.period_us * system.run.late_pct / 100.0, proc.period_us * system.run.too_late_pct / 100.0


def first_of_frame(records: np.ndarray) -> np.ndarray:
    """Whether each record is the first its DPU started in its minor cycle."""
    order = np.lexsort((records["start_ns"], records["minor"], records["dpu"]))
    dpu, minor = records["dpu"][order], records["minor"][order]
    out = np.zeros(len(records), dtype=bool)
    out[order] = np.r_[True, (dpu[1:] != dpu[:-1]) | (minor[1:] != minor[:-1])][: len(records)]
    return out


def first_of_frame_at(records: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """first_of_frame(records)[rows], from the records of the minor cycles of `rows` only: for
    a few rows, no sort of every record."""
    if not len(rows):
        return np.zeros(0, dtype=bool)
    minor = records["minor"]
    near = np.flatnonzero(np.isin(minor, np.unique(minor[rows])))
    return first_of_frame(records[near])[np.searchsorted(near, rows)]


def stall_explains(records: np.ndarray, first: np.ndarray) -> np.ndarray:
    """Whether the stalls account for each record's overshoot (-slack): those within its
    cycle, plus those its DPU had not caught up on (debt_ns) as far as they made it start
    late. The first record of a frame carries the frame's wake-up stall in both stall_ns and
    debt_ns (the executive's debt restarts from it): counted once."""
    debt = records["debt_ns"].astype(np.int64)
    own = records["stall_ns"].astype(np.int64)
    own = np.where(first, np.maximum(own - debt, 0), own)
    late = np.maximum(records["start_ns"].astype(np.int64) - records["sched_ns"].astype(np.int64), 0)
    return own + np.minimum(debt, late) >= -records["slack_ns"].astype(np.int64)


def unstalled_lateness_us(records: np.ndarray, lateness_us: np.ndarray) -> np.ndarray:
    """Each record's lateness (µs) less the stalls its DPU had not caught up on when it
    started (debt_ns): what the schedule and the design are late by. An early start stays."""
    debt_us = records["debt_ns"].astype(np.float64) / 1000.0
    return np.where(lateness_us > 0, np.maximum(lateness_us - debt_us, 0.0), lateness_us)


def event_latency_us(records: np.ndarray) -> np.ndarray:
    """event -> start of each record; NaN for a cycle that handled no event."""
    event = records["event_ns"]
    return np.where(event >= 0, (records["start_ns"] - event) / 1000.0, np.nan)


def event_response_us(records: np.ndarray) -> np.ndarray:
    """event -> end of the cycle's work of each record; NaN for a cycle that handled no event."""
    event = records["event_ns"]
    return np.where(event >= 0, (cycle_end_ns(records) - event) / 1000.0, np.nan)


def _events(proc: Process, mine: np.ndarray,
            done: np.ndarray) -> tuple[EventMetrics | None, Histogram | None]:
    """An event process's events, and the histogram of their latency."""
    if proc.sync != "event":
        return None, None
    got = done[done["event_ns"] >= 0]
    latency, latency_histogram = distribution(event_latency_us(got))
    return EventMetrics(
        event=proc.event,
        handled=len(got),
        dropped=int(mine["event_dropped"].sum()),
        queued_max=int(got["event_queued"].max()) if len(got) else 0,
        latency_us=latency,
        response_us=_latency(event_response_us(got)),
    ), latency_histogram


def input_counts(processes: list[ProcessMetrics]) -> dict[tuple[int, int], InputMetrics]:
    """The process table's counts of each input, by (process id, buffer id): what the buffer
    table says of its readers (latency.buffer_metrics)."""
    return {(int(p.id), int(i.buffer_id)): i for p in processes for i in p.inputs}


class _InputSums(NamedTuple):
    """What the counted input records of one process and buffer add up to."""

    records: int
    new: int
    dropped: int
    received: int


_NO_INPUTS = _InputSums(0, 0, 0, 0)


class InputPairs(NamedTuple):
    """The input records that count, by the (process, buffer) input of the config they are."""

    pairs: list[tuple[int, int]]  # every (process, buffer) input of the config, sorted
    at: np.ndarray  # per input record, its pair's index; len(pairs) when it does not count


def input_pairs(records: np.ndarray, inputs: np.ndarray, system: System,
                in_window: np.ndarray | None = None) -> InputPairs:
    """The InputPairs of `inputs`, the input records of `records`. An input record counts when
    its cycle record is in the window (`in_window`, as window_mask) and completed, so new +
    stale == cycles for every input; and when its process reads its buffer in `system`."""
    pairs = sorted({(int(p.id), int(b)) for p in system.processes for b in p.inputs})
    if not pairs or not len(inputs):
        return InputPairs(pairs, np.full(len(inputs), len(pairs), dtype=np.int32))
    counted = (window_mask(records, system, in_window) & completed(records))[inputs["record"]]
    return InputPairs(pairs, np.where(counted, _pair_index(inputs["process"], inputs["buffer"], pairs),
                                      len(pairs)))  # fmt: skip


def _input_sums(inputs: np.ndarray, pairs: InputPairs) -> dict[tuple[int, int], _InputSums]:
    """Per (process, buffer) input, the sums of its counted input records: bins counted once
    over all of them, not a gather of each process's inputs and a mask per buffer (0.7 s
    against 1.4-1.7 s over the 2·10^7 inputs of 10^7 records)."""
    bins = len(pairs.pairs) + 1  # the last: the inputs that do not count
    values = (inputs["new"] != 0, inputs["dropped"], inputs["received"])
    sums = [np.bincount(pairs.at, minlength=bins)] + [_exact_sums(pairs.at, v, bins) for v in values]
    return {pair: _InputSums(*(int(s[i]) for s in sums)) for i, pair in enumerate(pairs.pairs)}


# A table of (process, buffer) this large, at most, to look pairs up in (4 bytes an entry).
_PAIR_TABLE_MAX = 1 << 22


def _pair_index(process: np.ndarray, buffer: np.ndarray, pairs: list[tuple[int, int]]) -> np.ndarray:
    """Each (process, buffer) row's index in the sorted `pairs`, len(pairs) when it is none of
    them. Ids are int16 (as the records hold them): a gather from a table per id, then from a
    table of the pairs, where a binary search of every row took 0.35 s of 2·10^7."""
    procs = sorted({p for p, _ in pairs})
    bufs = sorted({b for _, b in pairs})
    if (len(procs) + 1) * (len(bufs) + 1) > _PAIR_TABLE_MAX:  # a huge system: search
        known = np.array([(p << 32) + b for p, b in pairs], dtype=np.int64)
        key = (process.astype(np.int64) << 32) + buffer.astype(np.int64)
        at = np.minimum(np.searchsorted(known, key), len(known) - 1)
        return np.where(known[at] == key, at, len(pairs))
    p_of = _dense(procs)  # id -> 0..len(procs)-1, len(procs) for any other id
    b_of = _dense(bufs)
    process, buffer = process.astype(np.int16, copy=False), buffer.astype(np.int16, copy=False)
    table = np.full((len(procs) + 1) * (len(bufs) + 1), len(pairs), dtype=np.int32)
    table[p_of[np.array([p for p, _ in pairs], dtype=np.int16).view(np.uint16)] * (len(bufs) + 1)
          + b_of[np.array([b for _, b in pairs], dtype=np.int16).view(np.uint16)]] = np.arange(len(pairs))
    return table[p_of[process.view(np.uint16)] * np.int32(len(bufs) + 1) + b_of[buffer.view(np.uint16)]]


def _dense(ids: list[int]) -> np.ndarray:
    """Per int16 id (viewed as uint16), its place in `ids`, or len(ids)."""
    out = np.full(1 << 16, len(ids), dtype=np.int32)
    out[np.array(ids, dtype=np.int16).view(np.uint16)] = np.arange(len(ids), dtype=np.int32)
    return out


# Of 32-bit integers, this many sum exactly in np.bincount's float64 weights (below 2**53).
_EXACT_ROWS = 1 << 21


def _exact_sums(key: np.ndarray, values: np.ndarray, bins: int) -> np.ndarray:
    """The sums of 32-bit integer `values` per `key`, exact: np.bincount over runs of
    _EXACT_ROWS, added up as int64."""
    out = np.zeros(bins, dtype=np.int64)
    for lo in range(0, len(values), _EXACT_ROWS):
        part = np.bincount(key[lo : lo + _EXACT_ROWS], weights=values[lo : lo + _EXACT_ROWS], minlength=bins)
        out += part.astype(np.int64)
    return out


def _input(sums: _InputSums, buffer_id: int, system: System) -> InputMetrics:
    desc = system.find_buffer(buffer_id)
    return InputMetrics(
        buffer=desc.name if desc is not None else f"buffer {buffer_id}",
        buffer_id=int(buffer_id),
        new=sums.new,
        stale=sums.records - sums.new,
        dropped=sums.dropped,
        received=sums.received,
    )
