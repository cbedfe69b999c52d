"""Generation windows: the part of a run that ran one config generation.

When the config changes mid-run (a live `skel push`), every timing record carries
the generation its cycle ran under, and the log holds every generation's config_t:
each window is measured with the System its own config describes (its own processes,
periods, allocation: a Generation), so a table never mixes two systems.

A window is measured in parts, each from the records of some of its DPUs (window_part),
then finished from all of them (finish_window): a long run's log is read a few DPUs at a
time, so that no more than their records are held at once. A DPU's rows, and each
process's, come whole from the part of its DPU; what crosses DPUs (a buffer's writer and
readers, a chain, a lockout's writer, a host's stalls) is kept by each part in what it
needs alone, and found once all parts are in.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

import skelmsg
from skeleton.host.model import System, from_config

from ..read.parallel import map_threads, table_bytes
from ..read.records import RECORD_DTYPE, RunRecords, select
from .chains import ChainMetrics, ChainRecords, chain_metrics
from .faults import (
    Behind,
    Deliveries,
    Fault,
    Lockout,
    behind_faults,
    behind_runs,
    delivery_faults,
    jam_faults,
    lockout_faults,
    lockouts_from_records,
    overrun_faults,
    skipping_faults,
    stall_events,
    stall_faults,
    stalled_dpus,
    stalled_writers,
)
from .latency import NO_OFFSETS, BufferMetrics, BufferParts, ClockOffsets, buffer_metrics, buffer_parts
from .links import LinkMetrics, link_metrics
from .metrics import (
    DpuMetrics,
    ProcessMetrics,
    dpu_metrics,
    input_counts,
    input_pairs,
    measured,
    process_metrics,
    smallest_per_id,
    warmup_end_ns,
    work_end_ns,
)
from .stats import group_slices


@dataclass(frozen=True)
class Generation:
    """One config generation of a run: its number (config_t.generation, which the wire alone
    carries: a system file has none) and the System its config_t describes."""

    number: int
    system: System

    @classmethod
    def of(cls, config: skelmsg.config_t) -> Generation:
        """The Generation a decoded config_t describes."""
        return cls(int(config.generation), from_config(config))


@dataclass
class WindowReport:
    generation: int
    start_ns: int | None  # host clock: the window's first measured release
    end_ns: int | None  # host clock: the end of its last measured cycle (work + idle)
    dpus: list[DpuMetrics]
    processes: list[ProcessMetrics]
    buffers: list[BufferMetrics] = field(default_factory=list)
    chains: list[ChainMetrics] = field(default_factory=list)
    faults: list[Fault] = field(default_factory=list)
    links: list[LinkMetrics] = field(default_factory=list)

    @property
    def duration_ms(self) -> float | None:
        if self.start_ns is None or self.end_ns is None:
            return None
        return (self.end_ns - self.start_ns) / 1e6


def window_records(run: RunRecords, generation: int) -> tuple[np.ndarray, np.ndarray]:
    """The records of one generation and their input records (re-indexed to them)."""
    # The run's one generation: its own tables, no copy of millions of rows (nor a look at
    # each record's generation).
    if run.generations == [generation]:
        return run.records, run.inputs
    return select(run.records, run.inputs, run.records["generation"] == generation)


class Span(NamedTuple):
    """A window's span on the host clock, (first release, last end), as a part of it shows it:
    over its measured records (`measured`), or over all of them when it has none measured; a
    window with a measured record anywhere spans its measured records alone."""

    start_ns: int | None
    end_ns: int | None
    measured: bool


def _span(records: np.ndarray, in_window: np.ndarray, clock: ClockOffsets) -> Span:
    if len(records) == 0:
        return Span(None, None, False)
    measured_any = bool(in_window.any())
    mine = in_window if measured_any else np.ones(len(records), dtype=bool)
    # Over the whole columns, the measured ones picked in the reductions: gathering the
    # measured records first copied every column it read (a second of 2 at 10^7 records).
    start = clock.to_host_many(records["dpu"], records["release_ns"])
    end = clock.to_host_many(records["dpu"], work_end_ns(records))
    top = np.iinfo(np.int64)
    return Span(int(start.min(where=mine, initial=top.max)), int(end.max(where=mine, initial=top.min)),
                measured_any)


@dataclass
class WindowPart:
    """One window as the records of some of its DPUs (`dpus`) show it: their rows of the DPU and
    process tables, and what the tables across DPUs need of them (see the module comment)."""

    dpus: set[int]
    dpu_rows: list[DpuMetrics]
    processes: list[ProcessMetrics]
    span: Span
    buffers: BufferParts
    chains: ChainRecords
    deliveries: Deliveries
    behind: list[Behind]
    stalls: np.ndarray  # faults.STALL_EVENT rows
    flagged: dict[int, Lockout]  # lockouts_from_records: what the timing records flagged
    first_cycles: dict[int, int]  # process -> its first cycle in the window (split_lockouts)
    sums_ns: dict[int, tuple[int, int, int]]  # DPU -> measured (compute, communicate, wait): _cross_check
    ends_ns: dict[int, int]  # warmup_end_ns of the window's records: earlier_ends_ns


def window_part(
    generation: Generation,
    records: np.ndarray,
    inputs: np.ndarray,
    dpus: set[int],
    clock: ClockOffsets = NO_OFFSETS,
    earlier: Mapping[int, int] | None = None,
    origin: Mapping[int, int] | None = None,
) -> WindowPart:
    """The WindowPart of `records` (the window's records of the DPUs `dpus`) and their input
    records. `earlier`: earlier_ends_ns of this window; `origin`: the run's first release per
    DPU (a fault's at_s counts from it), default the window's own."""
    # The tables and searches below read the same records and write nothing shared: numpy's
    # sorts, gathers and sums release the GIL, so on a run of millions of records they go
    # side by side on the machine's cores: the process table, the largest, first, the buffers'
    # and the chains' (the next in time and memory) last, so that those seldom hold their
    # temporaries at once (chains second: the peak of 10^7 records 1.96-1.98 GiB, last: 1.83-1.92).
    system = generation.system
    # Which records are in the measurement window: found once, read by every table (read-only:
    # the tables run side by side).
    win = measured(records, system)
    win.flags.writeable = False
    # Each process's first cycle here (split_lockouts), its keys the processes that ran (Deliveries).
    first_cycles = smallest_per_id(records["process"], records["cycle"])
    # Which (process, buffer) input each input record counts for: read by two tables, made once.
    pairs = input_pairs(records, inputs, system, win)
    pairs.at.flags.writeable = False
    tasks: dict[str, Callable[[], Any]] = {
        "processes": lambda: process_metrics(records, inputs, system, win, pairs),
        "behind": lambda: behind_runs(records, system, win, origin),
        "dpus": lambda: dpu_metrics(records, system, win, earlier),
        "span": lambda: _span(records, win, clock),
        "deliveries": lambda: Deliveries.of(records, inputs, system, set(first_cycles)),
        "stalls": lambda: stall_events(records, system),
        "sums": lambda: _sums_ns(records, win),
        "ends": lambda: warmup_end_ns(records),
        "buffers": lambda: buffer_parts(records, inputs, system, clock, win, pairs),
        "chains": lambda: ChainRecords.of(records, inputs, system, win),
    }
    done = dict(zip(tasks, map_threads(lambda task: task(), tasks.values(), table_bytes(records, inputs)),
                    strict=True))  # fmt: skip
    return WindowPart(
        dpus=dpus, dpu_rows=done["dpus"], processes=done["processes"], span=done["span"],
        buffers=done["buffers"], chains=done["chains"], deliveries=done["deliveries"], behind=done["behind"],
        stalls=done["stalls"],
        flagged=lockouts_from_records(records, {}),
        first_cycles=first_cycles,
        sums_ns=done["sums"], ends_ns=done["ends"],
    )


def finish_window(
    generation: Generation,
    parts: Sequence[WindowPart],
    lockouts: dict[int, Lockout],
    lost: Sequence[Fault],
    clock: ClockOffsets,
    stalls: np.ndarray,
    skips: np.ndarray,
    origin: Mapping[int, int],
) -> WindowReport:
    """Every table of one generation window from its parts (window_part). `lockouts`: the ones
    status_t reported in this window; `lost`: the run's lost DPUs (a fact of the whole run: last
    window only); `stalls`: the run's records with a stall (run_stalls: what a lockout's writer
    and a data wait behind are looked up in); `skips`: the run's skipped releases
    (latency.release_skips: what a buffer's loss looks up across a switch); `origin`: the run's
    first release per DPU."""
    system = generation.system
    processes = _rows(parts, system.processes, lambda p: p.dpu, lambda part: part.processes)
    flagged: dict[int, Lockout] = {}
    for part in parts:
        for proc, lock in part.flagged.items():
            flagged.setdefault(proc, lock)
    # What the timing records flagged and no status_t said (lockouts_from_records' rule).
    locks = {**lockouts, **{proc: lock for proc, lock in sorted(flagged.items()) if proc not in lockouts}}
    delivered, locks = delivery_faults(system, Deliveries.join(p.deliveries for p in parts), locks)
    # what the stalls explain, the writers' or the DPU's own: the whole run's records hold them
    platform = {**stalled_writers(locks, stalls, system, clock), **stalled_dpus(locks, stalls, system)}
    mine = stalls[stalls["generation"] == generation.number]
    behind = sorted((b for part in parts for b in part.behind), key=lambda b: b.dpu)
    spans = [part.span for part in parts if part.span.start_ns is not None]
    if any(s.measured for s in spans):
        spans = [s for s in spans if s.measured]
    # The buffers' and the chains' tables, the largest steps once every part is joined: their
    # sorts, searches and percentiles release the GIL, so they go side by side on the cores.
    chain_rows = ChainRecords.join([p.chains for p in parts])
    counted = input_counts(processes)
    buffers, chains = map_threads(lambda table: table(), [
        lambda: buffer_metrics(BufferParts.join(p.buffers for p in parts), system, skips, counted),
        lambda: chain_metrics(chain_rows, system, clock)], table_bytes(chain_rows.records, chain_rows.inputs))
    dpus = _rows(parts, system.dpus, lambda d: d.id, lambda part: part.dpu_rows)
    return WindowReport(
        generation=generation.number,
        start_ns=min((s.start_ns for s in spans), default=None),
        end_ns=max((s.end_ns for s in spans), default=None),
        dpus=dpus,
        processes=processes,
        buffers=buffers,
        chains=chains,
        links=link_metrics(system, buffers, processes, dpus),
        faults=(
            delivered
            + lockout_faults(locks, system, origin, platform)
            + jam_faults(locks, system, origin, platform)
            + behind_faults(behind, system, mine, clock)
            + skipping_faults(processes, system, {d.id: d.stall_ms for d in dpus})
            + stall_faults(np.concatenate([p.stalls for p in parts]), system, origin)
            + overrun_faults(processes)
            + list(lost)
        ),
    )


def _rows(parts: Sequence[WindowPart], described: Sequence[Any], dpu_of: Callable[[Any], int],
          rows_of: Callable[[WindowPart], list[Any]]) -> list[Any]:
    """A table's rows (one per `described` DPU or process, in the order the parts give them) each
    from the part of its DPU: the first part for a DPU no part holds (its row has no record)."""
    order = sorted(range(len(described)), key=lambda i: int(described[i].id))
    out = list(rows_of(parts[0]))
    for part in parts[1:]:
        rows = rows_of(part)
        for at, i in enumerate(order):
            if dpu_of(described[i]) in part.dpus:
                out[at] = rows[at]
    return out


# A record with a stall, of any window: what a lockout's writer and a data wait behind are
# looked up in (faults.writer_stall). Only these: a record without a stall adds nothing there.
# In the record's own types (a noisy machine's long run holds millions, kept to the report's end).
STALLED = np.dtype([(name, RECORD_DTYPE[name]) for name in ("dpu", "process", "generation", "release_ns",
                                                               "stall_ns")])


def run_stalls(records: np.ndarray) -> np.ndarray:
    """The records with a stall among `records` (every window's), as STALLED rows."""
    hit = records[records["stall_ns"] > 0]
    out = np.zeros(len(hit), dtype=STALLED)
    for name in STALLED.names or ():
        out[name] = hit[name]
    return out


def _sums_ns(records: np.ndarray, in_window: np.ndarray) -> dict[int, tuple[int, int, int]]:
    """Per DPU with measured records, the sums of their compute, communicate and wait times
    (what its report_t sums too: _cross_check)."""
    rows = np.flatnonzero(in_window)
    order, groups = group_slices(records["dpu"][rows])
    rows = rows[order]
    sums = {}
    for name in ("compute_ns", "comm_in_ns", "comm_out_ns", "blocked_ns", "idle_ns"):
        values = records[name][rows]
        sums[name] = {dpu: int(values[at].sum()) for dpu, at in groups.items()}
    return {dpu: (sums["compute_ns"][dpu], sums["comm_in_ns"][dpu] + sums["comm_out_ns"][dpu],
                  sums["blocked_ns"][dpu] + sums["idle_ns"][dpu]) for dpu in groups}


def earlier_ends_ns(before: Mapping[int, int], window: Mapping[int, int]) -> dict[int, int]:
    """When each DPU's work of the windows before the next one ended (metrics.warmup_end_ns),
    from when it ended before a window (`before`) and in it (its warmup_end_ns). A DPU behind
    its schedule at a live switch is still working on the old generation's cycles at the new
    one's first release: to the new window, that work is what warm-up work is to a run's first."""
    out = dict(before)
    for dpu, end in window.items():
        out[dpu] = max(end, out.get(dpu, end))
    return out


def split_lockouts(lockouts: dict[int, Lockout],
                   first_cycles: Sequence[Mapping[int, int]]) -> list[dict[int, Lockout]]:
    """Each lockout goes to the last window (each window's first cycle per process, in order)
    in which its process had run a cycle at or before the locked cycle; the last window
    otherwise."""
    out: list[dict[int, Lockout]] = [{} for _ in first_cycles]
    for proc, lock in lockouts.items():
        chosen = len(first_cycles) - 1
        for i in range(len(first_cycles) - 1, -1, -1):
            first = first_cycles[i].get(proc)
            if first is not None and first <= lock.cycle:
                chosen = i
                break
        if chosen >= 0:
            out[chosen][proc] = lock
    return out
