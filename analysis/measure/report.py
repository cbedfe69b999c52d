"""The report of one run: RunReport (what report.json holds) built from decoded
messages and timing records by `build_report`, for a log (run.py) and live views alike."""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import skelmsg

from ..read.logreader import Integrity
from ..read.records import RunRecords
from .chains import ChainMetrics
from .faults import (
    Fault,
    Heartbeats,
    dpu_lost_faults,
    first_release_ns,
    heartbeats_from_status,
    lockouts_from_status,
)
from .latency import NO_OFFSETS, BufferMetrics, ClockOffsets
from .metrics import DpuMetrics, ProcessMetrics
from .predicted import Predicted
from .stopped import Stopped, stopped_early
from .windows import (
    WindowReport,
    build_window,
    earlier_ends_ns,
    measured_once,
    split_lockouts,
    window_records,
)

COMPUTE_MODES = {0: "sleep", 1: "wall", 2: "cpu", 3: "work"}



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
    windows: list[WindowReport] = field(default_factory=list)
    clock_offsets: dict[int, int] = field(default_factory=dict)  # DPU -> last offset estimate (ns)
    # the prediction of the report generation's system file beside its figures: `skel run` and
    # `skel report` add it (RunAnalysis.add_prediction), since only the host tool can predict
    predicted: Predicted | None = None
    stopped: Stopped | None = None  # a command ended the run before its planned end

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


def build_report(
    config: Any,
    run: RunRecords,
    statuses: Sequence[Any] = (),
    reports: Sequence[Any] = (),
    integrity: Integrity | None = None,
    malformed: dict[str, int] | None = None,
    configs: Mapping[int, Any] | None = None,
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
    earlier = (configs or {}).items()
    by_generation = {g: c for g, c in earlier if g in run.generations and g < config.generation}
    by_generation[config.generation] = config
    generations = sorted(by_generation)
    parts = [window_records(run, g) for g in generations]
    # A report the logger missed may have been re-sent (host/repair.py): one per DPU.
    mine = list({r.dpu: r for r in reports if r.run_id == run.run_id}.values())
    locks = split_lockouts(lockouts_from_status(statuses, run.run_id), [p[0] for p in parts])
    if heartbeats is None:
        heartbeats = heartbeats_from_status((None, s) for s in statuses)
    # Every window's faults say when, from the run's first release: not from their window's.
    origin = first_release_ns(run.records)
    lost = dpu_lost_faults(config, run.records, heartbeats, run.run_id, origin, {r.dpu for r in mine})
    last_i = len(generations) - 1
    # Each window's measured records: its tables' and the cross-check's.
    masks = [measured_once(records, by_generation[g])
             for g, (records, _) in zip(generations, parts, strict=True)]
    ends_before = earlier_ends_ns([p[0] for p in parts])
    windows = [
        build_window(by_generation[g], records, inputs, locks[i], lost if i == last_i else (), clock,
                     run.records, masks[i], ends_before[i], origin)
        for i, (g, (records, inputs)) in enumerate(zip(generations, parts, strict=True))
    ]
    last = windows[-1]
    modes = {d.id: COMPUTE_MODES.get(d.compute, str(d.compute)) for d in config.dpus}
    modes.update({r.dpu: COMPUTE_MODES.get(r.compute, str(r.compute)) for r in mine})
    integ = integrity or Integrity(events=0)
    return RunReport(
        run_id=run.run_id,
        system=config.system,
        generation=config.generation,
        generations=run.generations,
        warmup_cycles=config.warmup_cycles,
        integrity=IntegrityReport(
            events=integ.events,
            corrupt_ranges=list(integ.corrupt_ranges),
            corrupt_bytes=integ.corrupt_bytes,
            truncated_tail=integ.truncated_tail,
            lost_batches=run.lost_batches,
            malformed={k: v for k, v in sorted((malformed or {}).items()) if v},
            duplicate_batches=run.duplicates,
            signed=integ.signed,
            checked=integ.checked,
            unauthenticated=integ.unauthenticated,
        ),
        dpus=last.dpus,
        processes=last.processes,
        faults=last.faults,
        compute_modes=modes,
        work_drift_pct={r.dpu: r.work_drift_pct for r in mine if r.compute == skelmsg.dpu_t.COMPUTE_WORK},
        cross_check=_cross_check([p[0] for p in parts], masks, mine),
        not_faithful=sorted(r.dpu for r in mine if r.faults & skelmsg.status_t.FAULT_NOT_FAITHFUL),
        buffers=last.buffers,
        chains=last.chains,
        windows=windows,
        clock_offsets=clock.latest(),
        stopped=stopped_early(commands, run.run_id),
    )


def _cross_check(windows: Sequence[np.ndarray], measured: Sequence[np.ndarray],
                 reports: Sequence[Any]) -> list[dict[str, Any]]:
    """The DPU's own running sums (report_t) beside ours over the measured records of every
    window (`measured`: each one's mask): they should agree. A DPU sums from its run's window
    on, across live switches (its warm-up is once a run), so ours add up every generation's.
    They differ when a push changed warmup_cycles or a DPU's longest period during the run: a
    window opens by its own config (metrics.window_start_ns), the DPU's by its first one."""
    out = []
    for rep in sorted(reports, key=lambda r: r.dpu):
        mine = [(records, mask & (records["dpu"] == rep.dpu)) for records, mask in zip(windows, measured,
                                                                                        strict=True)]
        out.append(
            {
                "dpu": rep.dpu,
                "compute_ms": [rep.compute_ns / 1e6, _sum_ms(mine, "compute_ns")],
                "communicate_ms": [rep.communicate_ns / 1e6, _sum_ms(mine, "comm_in_ns", "comm_out_ns")],
                "wait_ms": [rep.wait_ns / 1e6, _sum_ms(mine, "blocked_ns", "idle_ns")],
            }
        )
    return out


def _sum_ms(rows: Sequence[tuple[np.ndarray, np.ndarray]], *fields: str) -> float:
    """The sum of `fields` over the (records, mask) pairs, in ms."""
    return sum(int(records[f].sum(where=mask)) for records, mask in rows for f in fields) / 1e6
