"""One run's report from an LCM log alone: `analyze(path)` -> RunReport, and the
`skel report` command (`report_command`)."""

from __future__ import annotations

import dataclasses
import json
import os
import struct
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, TypeVar

import numpy as np

import skelmsg

from .chains import ChainMetrics
from .exitcodes import EXIT_BAD_INPUT, EXIT_FATAL_FLAW, EXIT_OK
from .faults import Fault, Heartbeat, dpu_lost_faults, heartbeats_from_status, lockouts_from_status
from .latency import NO_OFFSETS, BufferMetrics, ClockOffsets
from .logreader import Integrity, Log, open_log
from .metrics import DpuMetrics, ProcessMetrics, measured
from .records import RunRecords, load_run, run_ids
from .windows import WindowReport, build_window, split_lockouts, window_records

CONFIG_CHANNEL = "SKEL_CONFIG"
STATUS_CHANNEL = "SKEL_STATUS"
REPORT_CHANNEL = "SKEL_REPORT"
CLOCK_CHANNEL = "SKEL_CLOCK"
COMPUTE_MODES = {0: "sleep", 1: "wall", 2: "cpu", 3: "work"}

T = TypeVar("T")


class LogError(Exception):
    """The file cannot be analysed (unreadable, not an LCM log, no run in it)."""


@dataclass
class IntegrityReport:
    events: int
    corrupt_ranges: list[tuple[int, int]]
    corrupt_bytes: int
    truncated_tail: bool
    lost_batches: list[dict[str, int]]
    malformed: dict[str, int]  # channel -> messages that failed to decode (skipped)
    duplicate_batches: int = 0

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
    buffers: list[BufferMetrics] = field(default_factory=list)
    chains: list[ChainMetrics] = field(default_factory=list)
    windows: list[WindowReport] = field(default_factory=list)
    clock_offsets: dict[int, int] = field(default_factory=dict)  # DPU -> last offset estimate (ns)

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
    heartbeats: Sequence[Heartbeat] | None = None,
) -> RunReport:
    """The report of one run from decoded messages: shared by `analyze` and live views.

    `config` is the run's last generation; `configs` (generation -> config_t) adds a
    window for every earlier generation with timing records; `clock` holds the
    clock-offset estimates (none: every DPU on the host's clock); `heartbeats` the
    statuses with when they were heard (none: `statuses`, times unknown)."""
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
    lost = dpu_lost_faults(config, run.records, heartbeats, run.run_id)
    last_i = len(generations) - 1
    windows = [
        build_window(by_generation[g], records, inputs, locks[i], lost if i == last_i else (), clock)
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
        ),
        dpus=last.dpus,
        processes=last.processes,
        faults=last.faults,
        compute_modes=modes,
        work_drift_pct={r.dpu: r.work_drift_pct for r in mine if r.compute == skelmsg.dpu_t.COMPUTE_WORK},
        cross_check=_cross_check(parts[-1][0], config, mine),
        buffers=last.buffers,
        chains=last.chains,
        windows=windows,
        clock_offsets=clock.latest(),
    )


def _cross_check(records: np.ndarray, config: Any, reports: Sequence[Any]) -> list[dict[str, Any]]:
    """The DPU's own running sums (report_t) beside ours: they should agree."""
    window = records[measured(records, config)]
    out = []
    for rep in sorted(reports, key=lambda r: r.dpu):
        mine = window[window["dpu"] == rep.dpu]
        out.append(
            {
                "dpu": rep.dpu,
                "compute_ms": [rep.compute_ns / 1e6, int(mine["compute_ns"].sum()) / 1e6],
                "communicate_ms": [
                    rep.communicate_ns / 1e6,
                    int(mine["comm_in_ns"].sum() + mine["comm_out_ns"].sum()) / 1e6,
                ],
                "wait_ms": [rep.wait_ns / 1e6, int(mine["blocked_ns"].sum() + mine["idle_ns"].sum()) / 1e6],
            }
        )
    return out


def read_run_log(log_path: str | os.PathLike[str]) -> Log:
    """The log (or exported MCAP) of a run; LogError, one line for the user, when unreadable."""
    try:
        return open_log(log_path)
    except OSError as e:
        raise LogError(e.strerror or str(e)) from e


def analyze(log_path: str | os.PathLike[str], run_id: int | None = None) -> RunReport:
    """Analyse one run (default: the last run with timing records) from the log alone."""
    return analyze_log(read_run_log(log_path), run_id)


def analyze_log(log: Log, run_id: int | None = None) -> RunReport:
    if log.size == 0:
        raise LogError("empty file")
    if len(log) == 0:
        raise LogError("not an LCM log (no event found)")
    runs = run_ids(log)
    if not runs:
        raise LogError("no timing records (channel SKEL_TIMING) in this log")
    if run_id is None:
        run_id = runs[-1]
    elif run_id not in runs:
        raise LogError(f"no timing records for run {run_id} (runs in this log: {', '.join(map(str, runs))})")
    malformed: dict[str, int] = {}
    reports = _decode_all(log, REPORT_CHANNEL, skelmsg.report_t.decode, malformed)
    expected = {r.dpu: r.timing_batches for r in reports if r.run_id == run_id}
    run = load_run(log, run_id, expected_batches=expected)
    malformed["SKEL_TIMING"] = run.malformed
    configs = {}
    for g in run.generations:
        try:
            configs[g] = _config_for(log, g, malformed)
        except LogError:
            # A window without its config cannot be named (a stray batch, or the config was
            # never logged): only the others are reported, and the stray ones are counted.
            unnamed = int((run.records["generation"] == g).sum())
            malformed["SKEL_TIMING (no config for its generation)"] = (
                malformed.get("SKEL_TIMING (no config for its generation)", 0) + unnamed)
    if not configs:
        raise LogError(f"no config_t (channel SKEL_CONFIG) for generation {max(run.generations)}: "
                       "cannot name anything")
    config = configs.pop(max(configs))
    timed = _decode_timed(log, STATUS_CHANNEL, skelmsg.status_t.decode, malformed)
    statuses = [s for _, s in timed]
    offsets = _decode_all(log, CLOCK_CHANNEL, skelmsg.clock_offset_t.decode, malformed)
    clock = ClockOffsets.from_messages(offsets)
    return build_report(config, run, statuses, reports, log.integrity, malformed, configs, clock,
                        heartbeats_from_status(timed))


def _decode_timed(log: Log, channel: str, decode: Callable[[bytes], T],
                  malformed: dict[str, int]) -> list[tuple[int, T]]:
    """(utime_us, message) of every message on a channel; malformed ones are counted and skipped."""
    out = []
    for utime, data in log.messages(channel):
        try:
            out.append((utime, decode(bytes(data))))
        except Exception:  # any decoder failure means "malformed", never a crash
            malformed[channel] = malformed.get(channel, 0) + 1
    return out


def _decode_all(log: Log, channel: str, decode: Callable[[bytes], T], malformed: dict[str, int]) -> list[T]:
    """Decode every message on a channel; malformed ones are counted and skipped."""
    return [message for _, message in _decode_timed(log, channel, decode, malformed)]


_CONFIG_HEAD = struct.Struct(">q")  # config_t starts with its generation


def _config_for(log: Log, generation: int, malformed: dict[str, int]) -> Any:
    """The last config_t of a generation. Only its header is read for the others: a
    config (with the system file text) is re-sent periodically and is slow to decode."""
    fingerprint = skelmsg.config_t._get_packed_fingerprint()
    for _, data in reversed(log.messages(CONFIG_CHANNEL)):
        if len(data) < 16 or data[:8] != fingerprint:
            malformed[CONFIG_CHANNEL] = malformed.get(CONFIG_CHANNEL, 0) + 1
            continue
        if _CONFIG_HEAD.unpack_from(data, 8)[0] != generation:
            continue
        try:
            return skelmsg.config_t.decode(bytes(data))
        except Exception:
            malformed[CONFIG_CHANNEL] = malformed.get(CONFIG_CHANNEL, 0) + 1
    raise LogError(f"no config_t (channel SKEL_CONFIG) for generation {generation}: cannot name anything")


def report_command(path: str | os.PathLike[str], as_json: bool, run_id: int | None) -> int:
    """`skel report RUN.lcm [--json] [--run N]`: 0, 3 on a lockout/jam, 2 when unreadable."""
    try:
        report = analyze(path, run_id)
    except LogError as e:
        print(f"{path}: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if as_json:
        json.dump(report.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        from .tables import print_report  # rich is only needed for tables

        print_report(report)
    return EXIT_FATAL_FLAW if report.fatal else EXIT_OK
