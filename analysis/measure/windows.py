"""Generation windows: the part of a run that ran one config generation.

When the config changes mid-run (a live `skel push`), every timing record carries
the generation its cycle ran under, and the log holds every generation's config_t:
each window is measured with its own config (its own processes, periods,
allocation), so a table never mixes two systems.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..read.parallel import map_threads
from ..read.records import RunRecords, input_starts, select
from .chains import ChainMetrics, chain_metrics
from .faults import (
    Fault,
    Lockout,
    behind_faults,
    delivery_faults,
    first_release_ns,
    jam_faults,
    lockout_faults,
    lockouts_from_records,
    overrun_faults,
    skipping_faults,
    stall_faults,
    stalled_writers,
)
from .latency import NO_OFFSETS, BufferMetrics, ClockOffsets, buffer_metrics
from .metrics import (
    DpuMetrics,
    ProcessMetrics,
    dpu_metrics,
    measured,
    process_metrics,
    warmup_end_ns,
    work_end_ns,
)


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


def _span(records: np.ndarray, in_window: np.ndarray, clock: ClockOffsets) -> tuple[int | None, int | None]:
    if len(records) == 0:
        return None, None
    mine = in_window if in_window.any() else np.ones(len(records), dtype=bool)
    # Over the whole columns, the measured ones picked in the reductions: gathering the
    # measured records first copied every column it read (a second of 2 at 10^7 records).
    start = clock.to_host_many(records["dpu"], records["release_ns"])
    end = clock.to_host_many(records["dpu"], work_end_ns(records))
    top = np.iinfo(np.int64)
    return int(start.min(where=mine, initial=top.max)), int(end.max(where=mine, initial=top.min))


def build_window(
    config: Any,
    records: np.ndarray,
    inputs: np.ndarray,
    lockouts: dict[int, Lockout] | None = None,
    lost: Sequence[Fault] = (),
    clock: ClockOffsets = NO_OFFSETS,
    run_records: np.ndarray | None = None,
    in_window: np.ndarray | None = None,
    earlier: Mapping[int, int] | None = None,
    origin: Mapping[int, int] | None = None,
) -> WindowReport:
    """Every table of one generation window. `lockouts`: the ones status_t reported in
    this window; `lost`: the run's lost DPUs (a fact of the whole run: last window only);
    `run_records`: every window's records (what a buffer's loss looks up across a switch);
    `in_window`: measured(records, config), read-only, when the caller has it; `earlier`:
    earlier_ends_ns of this window; `origin`: the run's first release per DPU (a fault's
    at_s counts from it), default the window's own."""
    def delivery() -> tuple[list[Fault], dict[int, Lockout]]:
        return delivery_faults(config, records, inputs, lockouts_from_records(records, lockouts or {}))

    # The tables and searches below read the same records and write nothing shared: numpy's
    # sorts, gathers and sums release the GIL, so on a run of millions of records they go
    # side by side on the machine's cores (largest first, so neither core waits at the end).
    # Which records are in the measurement window: found once, read by every table (read-only:
    # the tables run side by side).
    win = measured_once(records, config) if in_window is None else in_window
    # Where each record's inputs start: read by two tables, made once (80 MB at 10^7 records).
    starts = input_starts(inputs, len(records))
    starts.flags.writeable = False
    tasks: dict[str, Callable[[], Any]] = {
        "processes": lambda: process_metrics(records, inputs, config, win, starts),
        "buffers": lambda: buffer_metrics(records, inputs, config, clock, run_records, win, starts),
        "chains": lambda: chain_metrics(records, inputs, config, clock, win),
        "behind": lambda: behind_faults(records, config, win, origin, clock),
        "dpus": lambda: dpu_metrics(records, config, win, earlier),
        "span": lambda: _span(records, win, clock),
        "delivery": delivery,
        "stalls": lambda: stall_faults(records, config, origin),
    }
    done = dict(zip(tasks, map_threads(lambda task: task(), tasks.values(), _work_bytes(records, inputs)),
                    strict=True))  # fmt: skip
    processes = done["processes"]
    delivered, locks = done["delivery"]
    # a lockout's at_s counts from the run's first release, as the other faults' do
    first = first_release_ns(records) if origin is None else origin
    # what the writers' stalls explain: the whole run's records hold a writer's DPU's cycles
    platform = stalled_writers(locks, records if run_records is None else run_records, config, clock)
    start, end = done["span"]
    return WindowReport(
        generation=int(config.generation),
        start_ns=start,
        end_ns=end,
        dpus=done["dpus"],
        processes=processes,
        buffers=done["buffers"],
        chains=done["chains"],
        faults=(
            delivered
            + lockout_faults(locks, config, first, platform)
            + jam_faults(locks, config, first, platform)
            + done["behind"]
            + skipping_faults(processes, config)
            + done["stalls"]
            + overrun_faults(processes)
            + list(lost)
        ),
    )


def earlier_ends_ns(windows: Sequence[np.ndarray]) -> list[dict[int, int]]:
    """Per window (records per window, in generation order): when each DPU's work of the
    windows before it ended (metrics.warmup_end_ns). A DPU behind its schedule at a live
    switch is still working on the old generation's cycles at the new one's first release:
    to the new window, that work is what warm-up work is to a run's first."""
    out: list[dict[int, int]] = [{}]
    for records in windows[:-1]:
        ends = dict(out[-1])
        for dpu, end in warmup_end_ns(records).items():
            ends[dpu] = max(end, ends.get(dpu, end))
        out.append(ends)
    return out


def measured_once(records: np.ndarray, config: Any) -> np.ndarray:
    """measured(records, config), read-only: the window's tables share it side by side."""
    win = measured(records, config)
    win.flags.writeable = False
    return win


def _work_bytes(records: np.ndarray, inputs: np.ndarray) -> int:
    """About how many bytes of columns the window's tables read (map_threads' threshold)."""
    return len(records) * records.dtype.itemsize + len(inputs) * inputs.dtype.itemsize


def split_lockouts(lockouts: dict[int, Lockout], windows: Sequence[np.ndarray]) -> list[dict[int, Lockout]]:
    """Each lockout goes to the last window (records per window, in order) in which its
    process had run a cycle at or before the locked cycle; the last window otherwise."""
    out: list[dict[int, Lockout]] = [{} for _ in windows]
    for proc, lock in lockouts.items():
        chosen = len(windows) - 1
        for i in range(len(windows) - 1, -1, -1):
            cycles = windows[i]["cycle"][windows[i]["process"] == proc]
            if len(cycles) and int(cycles.min()) <= lock.cycle:
                chosen = i
                break
        if chosen >= 0:
            out[chosen][proc] = lock
    return out
