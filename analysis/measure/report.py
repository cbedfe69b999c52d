"""The report of one run: RunReport (what report.json holds) built from decoded
messages and timing records by `build_report`, for a log (run.py) and live views alike."""

from __future__ import annotations

import dataclasses
from collections.abc import Collection, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import skelmsg
from skeleton.host.model import COMPUTE

from ..read.coltable import ColumnTable
from ..read.logreader import Integrity
from ..read.records import INPUT_DTYPE, RECORD_DTYPE, RunRecords
from .chains import ChainMetrics
from .faults import (
    Fault,
    Heartbeats,
    code_faults,
    dpu_lost_faults,
    first_release_ns,
    heartbeats_from_status,
    lockouts_from_status,
)
from .latency import NO_OFFSETS, BufferMetrics, ClockOffsets, release_skips
from .links import LinkMetrics
from .metrics import DpuMetrics, ProcessMetrics
from .predicted import Predicted
from .simulated import Simulation
from .stopped import Stopped, stopped_early
from .windows import (
    Generation,
    WindowPart,
    WindowReport,
    earlier_ends_ns,
    finish_window,
    run_stalls,
    split_lockouts,
    window_part,
    window_records,
)

COMPUTE_MODES = {value: name for name, value in COMPUTE.items()}  # report_t.compute -> its name



@dataclass
class IntegrityReport:
    events: int
    corrupt_ranges: list[tuple[int, int]]
    corrupt_bytes: int
    truncated_tail: bool
    lost_batches: list[dict[str, int]]
    malformed: dict[str, int]  # channel -> messages that failed to decode (skipped)
    duplicate_batches: int = 0
    signed: bool = False         # the run's messages carry seals (a key was in use)
    checked: bool = False        # ... and the analysis had that key: only genuine messages used
    unauthenticated: int = 0     # messages the key check left out

    @property
    def damaged(self) -> bool:
        return bool(self.corrupt_ranges or self.lost_batches)


@dataclass
class RunReport:
    """One run. With one config generation, dpus/processes/buffers/chains/faults are
    the whole run; when the config changed mid-run they are the LAST generation
    window's, and `windows` holds every window (one entry for a single generation)."""

    run_id: int
    system: str
    generation: int
    generations: list[int]  # every generation with timing records in the run
    warmup_cycles: int
    integrity: IntegrityReport
    dpus: list[DpuMetrics]
    processes: list[ProcessMetrics]
    faults: list[Fault]
    compute_modes: dict[int, str] = field(default_factory=dict)
    # WORK: how much slower (%) the kernel ran at the run's start than at the DPU's start-up
    work_drift_pct: dict[int, float] = field(default_factory=dict)
    cross_check: list[dict[str, Any]] = field(default_factory=list)  # report_t vs records, per DPU
    # DPUs whose tasking threads got no SCHED_FIFO or pinning (report_t FAULT_NOT_FAITHFUL):
    # the kernel's time sharing stood in for fixed-priority preemptive scheduling
    not_faithful: list[int] = field(default_factory=list)
    buffers: list[BufferMetrics] = field(default_factory=list)
    chains: list[ChainMetrics] = field(default_factory=list)
    links: list[LinkMetrics] = field(default_factory=list)
    windows: list[WindowReport] = field(default_factory=list)
    clock_offsets: dict[int, int] = field(default_factory=dict)  # DPU -> last offset estimate (ns)
    # the prediction of the report generation's system file beside its figures: `skel run` and
    # `skel report` add it (RunAnalysis.add_prediction), since only the host tool can predict
    predicted: Predicted | None = None
    stopped: Stopped | None = None  # a command ended the run before its planned end
    simulated: bool = False  # the run itself ran on virtual time (`skel simulate`): no platform in it
    # a simulation of the report generation's system beside this measured run, per DPU: what the
    # platform cost (`skel run` adds it, RunAnalysis.add_simulation)
    simulation: Simulation | None = None

    @property
    def fatal(self) -> bool:
        """A lockout, a jam or a DPU behind its schedule for no fault of the platform:
        the architecture does not work."""
        return any(f.fatal for f in self.faults)

    def to_json(self) -> dict[str, Any]:
        # The chain series (one sample per cycle) stay in the API: report.json keeps
        # their summary and histogram.
        out = dataclasses.asdict(dataclasses.replace(self, chains=_no_series(self.chains), windows=[]))
        out["integrity"]["corrupt_ranges"] = [list(r) for r in self.integrity.corrupt_ranges]
        for chain in out["chains"]:
            chain.pop("series")
        extras = {"compute_mode": out.pop("compute_modes"), "work_drift_pct": out.pop("work_drift_pct")}
        _add_dpu_extras(out["dpus"], extras)
        out["windows"] = [_window_json(w, extras) for w in self.windows]
        out["fatal"] = self.fatal
        return out


def _no_series(chains: list[ChainMetrics]) -> list[ChainMetrics]:
    return [dataclasses.replace(c, series=None) for c in chains]


def _add_dpu_extras(dpus: list[dict[str, Any]], extras: dict[str, dict[int, Any]]) -> None:
    """What the DPUs' own report_t says of each (compute mode, WORK drift) beside our rows."""
    for dpu in dpus:
        for key, per_dpu in extras.items():
            dpu[key] = per_dpu.get(dpu["id"])


def _window_json(window: WindowReport, extras: dict[str, dict[int, Any]]) -> dict[str, Any]:
    out = dataclasses.asdict(dataclasses.replace(window, chains=_no_series(window.chains)))
    for chain in out["chains"]:
        chain.pop("series")
    _add_dpu_extras(out["dpus"], extras)
    out["duration_ms"] = window.duration_ms
    return out


@dataclass
class RunPart:
    """One run as the records of some of its DPUs show it: their batches' counts, a
    WindowPart per window, and what the report looks up across DPUs (their first releases,
    stalls and skipped releases)."""

    counts: RunRecords  # the part's RunRecords less its records and inputs, let go with the part
    windows: list[WindowPart]
    origin: dict[int, int]  # faults.first_release_ns
    stalls: np.ndarray  # windows.run_stalls
    skips: np.ndarray  # latency.release_skips


def run_part(run: RunRecords, generations: Sequence[Generation], dpus: set[int],
             clock: ClockOffsets = NO_OFFSETS) -> RunPart:
    """The RunPart of `run` (the records of the DPUs `dpus`) for the windows of `generations`
    (report_generations)."""
    origin = first_release_ns(run.records) if run.origin_ns is None else run.origin_ns
    windows: list[WindowPart] = []
    earlier: dict[int, int] = {}  # when each DPU's work of the windows before ended
    for generation in generations:
        records, inputs = window_records(run, generation.number)
        windows.append(window_part(generation, records, inputs, dpus, clock, earlier, origin))
        earlier = earlier_ends_ns(earlier, windows[-1].ends_ns)
    # not a slice of the records: it would hold their columns
    counts = dataclasses.replace(run, records=ColumnTable.empty(RECORD_DTYPE),
                                 inputs=ColumnTable.empty(INPUT_DTYPE))
    return RunPart(counts, windows, origin, run_stalls(run.records), release_skips(run.records))


def report_generations(config: skelmsg.config_t, generations: Collection[int],
                       configs: Mapping[int, skelmsg.config_t] | None) -> list[Generation]:
    """Every window of a report whose last generation is `config`'s, from the decoded config_t:
    each earlier one of `configs` (generation -> config_t) with timing records (in
    `generations`), in order, as the Generation its config describes."""
    by_generation = {g: c for g, c in (configs or {}).items() if g in generations and g < config.generation}
    by_generation[config.generation] = config
    return [Generation.of(by_generation[g]) for g in sorted(by_generation)]


def build_report(
    config: skelmsg.config_t,
    run: RunRecords,
    statuses: Sequence[Any] = (),
    reports: Sequence[Any] = (),
    integrity: Integrity | None = None,
    malformed: dict[str, int] | None = None,
    configs: Mapping[int, skelmsg.config_t] | None = None,
    clock: ClockOffsets | None = None,
    heartbeats: Heartbeats | None = None,
    commands: Sequence[tuple[int, Any]] = (),
) -> RunReport:
    """The report of one run from decoded messages: shared by `analyze` and live views.

    `config` is the run's last generation; `configs` (generation -> config_t) adds a
    window for every earlier generation with timing records; `clock` holds the
    clock-offset estimates (none: every DPU on the host's clock); `heartbeats` the
    statuses with when they were heard (none: `statuses`, times unknown); `commands` the
    command_t with when they were heard (stopped.py)."""
    clock = clock or NO_OFFSETS
    windows = report_generations(config, run.generations, configs)
    # one part: every DPU's rows come from it
    parts = [run_part(run, windows, {int(d.id) for g in windows for d in g.system.dpus}, clock)]
    if heartbeats is None:
        heartbeats = heartbeats_from_status((None, s) for s in statuses)
    return finish_report(windows, parts, heartbeats, statuses, reports, integrity, malformed, clock, commands)


def finish_report(
    windows: Sequence[Generation],
    parts: Sequence[RunPart],
    heartbeats: Heartbeats,
    statuses: Sequence[Any] = (),
    reports: Sequence[Any] = (),
    integrity: Integrity | None = None,
    malformed: dict[str, int] | None = None,
    clock: ClockOffsets | None = None,
    commands: Sequence[tuple[int, Any]] = (),
    last_always: bool = True,
) -> RunReport:
    """The report of one run from its parts (run_part of each few DPUs, for the `windows`:
    report_generations), as build_report's arguments say; `statuses`: those that name
    lockouts suffice. A window of no decoded record is left out, but for the last of `windows`
    when `last_always` (a live view's config, before its first records come)."""
    clock = clock or NO_OFFSETS
    run_id = parts[0].counts.run_id
    generations = sorted({g for part in parts for g in part.counts.generations})
    kept = [i for i, g in enumerate(windows)
            if g.number in generations or (last_always and i == len(windows) - 1)]
    newest = windows[kept[-1]]
    system = newest.system
    window_parts = [[part.windows[i] for part in parts] for i in kept]
    # A report the logger missed may have been re-sent (host/live/repair.py): one per DPU.
    mine = list({r.dpu: r for r in reports if r.run_id == run_id}.values())
    firsts = [_smallest([p.first_cycles for p in wp]) for wp in window_parts]
    locks = split_lockouts(lockouts_from_status(statuses, run_id), firsts)
    # Every window's faults say when, from the run's first release: not from their window's.
    origin = _smallest([part.origin for part in parts])
    lost = dpu_lost_faults(system, heartbeats, run_id, origin, {r.dpu for r in mine})
    stalls = np.concatenate([part.stalls for part in parts])
    skips = np.concatenate([part.skips for part in parts])
    last_i = len(kept) - 1
    finished = [
        finish_window(windows[k], wp, locks[i], lost if i == last_i else (), clock, stalls, skips, origin)
        for i, (k, wp) in enumerate(zip(kept, window_parts, strict=True))
    ]
    last = finished[-1]
    modes = {d.id: d.compute for d in system.dpus}
    modes.update({r.dpu: COMPUTE_MODES.get(r.compute, str(r.compute)) for r in mine})
    integ = integrity or Integrity(events=0)
    return RunReport(
        run_id=run_id,
        system=system.name,
        generation=newest.number,
        generations=generations,
        warmup_cycles=system.run.warmup_cycles,
        integrity=IntegrityReport(
            events=integ.events,
            corrupt_ranges=list(integ.corrupt_ranges),
            corrupt_bytes=integ.corrupt_bytes,
            truncated_tail=integ.truncated_tail,
            lost_batches=sorted((b for p in parts for b in p.counts.lost_batches), key=lambda b: b["dpu"]),
            malformed={k: v for k, v in sorted((malformed or {}).items()) if v},
            duplicate_batches=sum(part.counts.duplicates for part in parts),
            signed=integ.signed,
            checked=integ.checked,
            unauthenticated=integ.unauthenticated,
        ),
        dpus=last.dpus,
        processes=last.processes,
        faults=[*last.faults, *code_faults(system, mine)],
        compute_modes=modes,
        work_drift_pct={r.dpu: r.work_drift_pct for r in mine if r.compute == skelmsg.dpu_t.COMPUTE_WORK},
        cross_check=_cross_check(window_parts, mine),
        not_faithful=sorted(r.dpu for r in mine if r.faults & skelmsg.status_t.FAULT_NOT_FAITHFUL),
        buffers=last.buffers,
        chains=last.chains,
        links=last.links,
        windows=finished,
        clock_offsets=clock.latest(),
        stopped=stopped_early(commands, run_id),
    )


def holds_its_processes(parts: Sequence[RunPart], windows: Sequence[Generation]) -> bool:
    """Whether every process's records of each window (of `windows`) are in the part of its
    DPU: a process's row is made from that part alone (windows.finish_window), so a process
    with records in another DPU's batches needs the run read as one part."""
    for i, generation in enumerate(windows):
        dpu_of = {int(p.id): int(p.dpu) for p in generation.system.processes}
        for part in parts:
            window = part.windows[i]
            if any(dpu_of.get(proc) not in window.dpus for proc in window.deliveries.ran):
                return False
    return True


def _smallest(values: Iterable[Mapping[int, int]]) -> dict[int, int]:
    """Per key of any of `values`, the smallest value it has in them."""
    out: dict[int, int] = {}
    for mapping in values:
        for key, value in mapping.items():
            out[key] = min(value, out.get(key, value))
    return out


def _cross_check(windows: Sequence[Sequence[WindowPart]], reports: Sequence[Any]) -> list[dict[str, Any]]:
    """The DPU's own running sums (report_t) beside ours over the measured records of every
    window (its parts' sums_ns): they should agree. A DPU sums from its run's window
    on, across live switches (its warm-up is once a run), so ours add up every generation's.
    They differ when a push changed warmup_cycles or a DPU's longest period during the run: a
    window opens by its own config (metrics.window_start_ns), the DPU's by its first one."""
    out = []
    for rep in sorted(reports, key=lambda r: r.dpu):
        sums = [part.sums_ns.get(rep.dpu, (0, 0, 0)) for parts in windows for part in parts]
        ours = [sum(s[k] for s in sums) / 1e6 for k in range(3)]
        out.append(
            {
                "dpu": rep.dpu,
                "compute_ms": [rep.compute_ns / 1e6, ours[0]],
                "communicate_ms": [rep.communicate_ns / 1e6, ours[1]],
                "wait_ms": [rep.wait_ns / 1e6, ours[2]],
            }
        )
    return out
