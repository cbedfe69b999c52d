"""The live tables, kept up to date as records arrive: per DPU its utilization shares,
overruns and measured records; per process its cycles, overruns, release latency
(p50/p99/max) and late / too late cycles. Each figure is metrics.py's definition, so
after any chunking the tables equal `skel report`'s for the same records (as long as a
DPU's summed times fit in int64 ns, which a damaged record of 10^18 ns may break: the
tally's sums are exact where the report's numpy sums wrap).

`skel watch` refreshes every 0.4 s: rebuilding the report from every record heard costs
seconds at 10^6 records. Here only the records that came since the last refresh are
decoded and tallied: sums, counts and extremes are added, and each process's release
latencies go into its stats.SortedSamples (two sorted runs, the percentiles read by binary
search: 0.12 ms a refresh for an hour of a 200 Hz process, where one sorted array copied
and read whole took 5.5 ms); what grows is those latencies' memory, 8 bytes a cycle. Only when a DPU's
measurement window moves (a batch older than any heard before arrives late) is the
generation tallied again from all its records; once a live view's
store has forgotten the oldest (host/live/recordstore.py), the window stays where it is and
such a batch counts as before it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import skelmsg

from ..read.records import RunRecords
from .metrics import (
    completed,
    elapsed_ns,
    late_limits_us,
    lateness_us,
    latest,
    measured,
    overran,
    release_latency_us,
    shares_ns,
    utilization_pct,
    warmup_end_ns,
    window_start_ns,
    work_end_ns,
)
from .stats import LatencyUs, SortedSamples, group_slices
from .windows import Generation


@dataclass
class DpuTally:
    """One DPU's measured records so far: the columns of its row in the live table."""

    id: int
    records: int = 0
    overruns: int = 0
    compute_ns: int = 0
    communicate_ns: int = 0
    wait_ns: int = 0
    first_release_ns: int | None = None
    first_start_ns: int | None = None
    last_end_ns: int | None = None
    # metrics.warmup_end_ns of its records before the window, and of its earlier generations'
    warmup_end_ns: int | None = None

    @property
    def elapsed_ms(self) -> float | None:
        elapsed = self._elapsed_ns()
        return None if elapsed is None else elapsed / 1e6

    def _elapsed_ns(self) -> int | None:
        if self.first_release_ns is None or self.first_start_ns is None or self.last_end_ns is None:
            return None
        return elapsed_ns(self.first_release_ns, self.first_start_ns, self.last_end_ns, self.warmup_end_ns)

    @property
    def shares_pct(self) -> tuple[float | None, float | None, float | None, float | None]:
        """(% compute, % communicate, % wait, % overhead): the report's DpuMetrics figures."""
        return utilization_pct(self.compute_ns, self.communicate_ns, self.wait_ns, self._elapsed_ns())

    def add(self, mine: np.ndarray) -> None:
        if len(mine) == 0:
            return
        compute, communicate, wait = shares_ns(mine)
        self.compute_ns += compute
        self.communicate_ns += communicate
        self.wait_ns += wait
        self.records += len(mine)
        self.overruns += int(np.count_nonzero(overran(mine[completed(mine)])))
        first, start, end = (int(mine["release_ns"].min()), int(mine["start_ns"].min()),
                             int(work_end_ns(mine).max()))
        self.first_release_ns = first if self.first_release_ns is None else min(first, self.first_release_ns)
        self.first_start_ns = start if self.first_start_ns is None else min(start, self.first_start_ns)
        self.last_end_ns = end if self.last_end_ns is None else max(end, self.last_end_ns)

    def add_warmup(self, end: int | None) -> None:
        """When its work before the window ended (metrics.warmup_end_ns), as far as known."""
        self.warmup_end_ns = latest(end, self.warmup_end_ns)


@dataclass
class ProcessTally:
    """One process's completed measured cycles so far."""

    id: int
    name: str
    dpu: int
    late_limits_us: tuple[float, float]
    cycles: int = 0
    overruns: int = 0
    late: int = 0
    too_late: int = 0
    latencies_us: SortedSamples = field(default_factory=SortedSamples)

    @property
    def latency_us(self) -> LatencyUs:
        return self.latencies_us.latency_us()

    def add(self, mine: np.ndarray) -> None:
        done = mine[completed(mine)]
        if len(done) == 0:
            return
        self.cycles += len(done)
        self.overruns += int(np.count_nonzero(overran(done)))
        lateness = lateness_us(done)
        self.late += int(np.count_nonzero(lateness > self.late_limits_us[0]))
        self.too_late += int(np.count_nonzero(lateness > self.late_limits_us[1]))
        self.latencies_us.add(release_latency_us(done))


class GenerationTally:
    """The live tables of one config generation's window."""

    def __init__(self, generation: Generation) -> None:
        self.system = generation.system
        self.generation = generation.number
        self.dpus = [DpuTally(int(d.id)) for d in sorted(self.system.dpus, key=lambda d: d.id)]
        self.processes = [
            ProcessTally(int(p.id), p.name, int(p.dpu), late_limits_us(p, self.system))
            for p in sorted(self.system.processes, key=lambda p: p.id)
        ]
        self._dpu = {d.id: d for d in self.dpus}
        self._process = {p.id: p for p in self.processes}
        self.window_starts: dict[int, int] = {}

    def add(self, records: np.ndarray, move: bool = True) -> bool:
        """Tally a chunk of this generation's records; False (nothing tallied) when the chunk
        would open a DPU's measurement window earlier than the records tallied so far. With
        `move` false (the records before were forgotten: the tables cannot begin again), the
        windows stay, and what ran before them counts as before."""
        if len(records) == 0:
            return True
        starts = window_start_ns(records, self.system)
        if move and any(d in self.window_starts and s < self.window_starts[d] for d, s in starts.items()):
            return False
        for dpu, start in starts.items():
            self.window_starts.setdefault(dpu, start)
        in_window = measured(records, self.system, self.window_starts)
        window, before = records[in_window], records[~in_window]
        order, by_dpu = group_slices(window["dpu"])
        for dpu, rows in by_dpu.items():
            if dpu in self._dpu:
                self._dpu[dpu].add(window[order[rows]])
        self.add_earlier(before)
        order, by_process = group_slices(window["process"])
        for proc, rows in by_process.items():
            if proc in self._process:
                self._process[proc].add(window[order[rows]])
        return True

    def add_earlier(self, records: np.ndarray) -> None:
        """Records that ran before the window: its own warm-up, or an earlier generation's."""
        for dpu, end in warmup_end_ns(records).items():
            if dpu in self._dpu:
                self._dpu[dpu].add_warmup(end)

    @property
    def elapsed_ms(self) -> float:
        return max((d.elapsed_ms or 0.0 for d in self.dpus), default=0.0)


class RunTally:
    """The live tables of a followed run's newest generation (with a config), fed the
    run's records as they grow."""

    def __init__(self, run_id: int) -> None:
        self.run_id = run_id
        self.tables: GenerationTally | None = None
        self.seen = 0  # records of the run heard and tallied (or passed over: another generation's)

    def update(self, run: RunRecords, configs: dict[int, skelmsg.config_t]) -> GenerationTally | None:
        """Tally the records of `run` past those seen before (`run` only ever grows, though its
        oldest may be forgotten: run.first; `configs`: the decoded config_t by generation, as
        heard)."""
        newest = max((g for g in run.generations if g in configs), default=None)
        if newest is None:
            return None
        if self.tables is None or self.tables.generation != newest:
            self.tables, self.seen = GenerationTally(Generation.of(configs[newest])), 0
        fresh = run.records[max(0, self.seen - run.first) :]
        self.seen = run.first + len(run.records)
        # The windows of the report are the generations with a config: so are the earlier ones.
        earlier = [g for g in configs if g < newest]
        if not _tally(self.tables, fresh, earlier, move=not run.first):
            self.tables = GenerationTally(Generation(newest, self.tables.system))
            _tally(self.tables, run.records, earlier)
        return self.tables


def _tally(tables: GenerationTally, records: np.ndarray, earlier: list[int], move: bool = True) -> bool:
    """GenerationTally.add of the records of its generation, having seen those of `earlier`."""
    if earlier:
        tables.add_earlier(records[np.isin(records["generation"], earlier)])
    return tables.add(_of(records, tables.generation), move)


def _of(records: np.ndarray, generation: int) -> np.ndarray:
    mine = records["generation"] == generation
    return records if mine.all() else records[mine]
