"""One run read once: `load_run(path)` -> RunAnalysis, the one result every view takes.

A RunAnalysis holds the log's events, the run's timing records (every generation),
the decoded control-plane messages (configs by generation, statuses, DPU reports,
clock estimates), the report (report.json) and a map from each DPU's clock to wall
clock, all from one read of the file and one decode of each message (the statuses', the
many, integers read in bulk for the report, and read whole only by the export).

Wall clock: timing records are stamped with the DPU's CLOCK_MONOTONIC, which means
nothing outside the DPU. Each status_t carries a (mono_ns, utc_ns) pair read at one
instant, so utc - mono is that DPU's offset; the median over its status messages is
robust to a stalled heartbeat. A DPU with no status message falls back to its timing
batches: a batch is logged after every record in it started, so
min(logged utime - latest start) bounds the offset from above (by the batching delay).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Mapping
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from functools import cached_property
from typing import Any

import numpy as np

import skelmsg
from skeleton.host.model import System, from_config
from skelmsg.contract import CONFIG_CHANNEL, SIMULATED_SENDER, TIMING_CHANNEL

from ..read.logreader import Log
from ..read.messages import LogError, Messages, open_run_log, published_batches, read_messages
from ..read.records import IMPOSSIBLE, Heads, RunRecords, load_records, run_ids, run_usual_sizes, timing_heads
from ..read.seal import KeyFileError, authenticate
from .columns import Table, faults_table, process_names, receptions_table, report_tables, timing_table
from .faults import HEARTBEAT_FIELDS, Heartbeats, heartbeats
from .latency import ClockOffsets
from .predicted import PLATFORM, REAL_CODE, SIMPLIFIED, Predictor, beside
from .report import RunPart, RunReport, finish_report, holds_its_processes, report_generations, run_part
from .simulated import simulation_beside
from .windows import Generation, window_records

NO_CONFIG = f"{TIMING_CHANNEL} (no config for its generation)"


@dataclass
class RunAnalysis:
    """A run as read from its log: see the module comment."""

    log: Log
    heads: Heads  # the header of every timing batch in the log (records.timing_heads)
    messages: Messages
    report: RunReport
    clock: ClockOffsets  # DPU clock -> host clock (SKEL_CLOCK estimates), as the report uses
    utc_offset_ns: dict[int, int] = field(default_factory=dict)  # dpu -> utc_ns - mono_ns
    # every generation of the run (`recorded`); None when the report was made a few DPUs at a time
    held: RunRecords | None = field(default=None, repr=False)
    usual: dict[str, float] | None = None  # the bounds of impossible records the parts used

    _windows: dict[int, tuple[Any, Any]] = field(default_factory=dict, init=False, repr=False)
    _systems: dict[int, System] = field(default_factory=dict, init=False, repr=False)

    @property
    def path(self) -> str:
        return self.log.path

    @property
    def recorded(self) -> RunRecords:
        """Every timing record of the run (every generation). A long run's report is made a few
        DPUs at a time (PART_RECORDS), holding no more than theirs: its records are read again
        here, for the views that need every one of them (export, the timing table, plots)."""
        if self.held is None:
            run_id = self.report.run_id
            self.held = load_records(self.log, run_id, published_batches(self.log, run_id), self.heads,
                                     usual=self.usual)
        return self.held

    @property
    def config(self) -> skelmsg.config_t:
        """The config_t of the report's generation (the run's last), as the log holds it: the
        export attaches it (its send time); the analysis reads `system`."""
        return self.messages.configs[self.report.generation]

    @property
    def system(self) -> System:
        """The report generation's system, as its config_t describes it (the typed model)."""
        return self.system_of(self.report.generation)

    def system_of(self, generation: int) -> System:
        """The system a generation's config_t describes (skeleton.host.model.from_config)."""
        if generation not in self._systems:
            self._systems[generation] = from_config(self.messages.configs[generation])
        return self._systems[generation]

    def window(self, generation: int) -> tuple[Any, Any]:
        """The process-cycle records of one generation window (a ColumnTable of RECORD_DTYPE:
        three counters are narrower than int64, as on the wire; `timing` gives every field
        as int64) and their input records ("record" indexes the former)."""
        if generation not in self._windows:
            # The run's own tables when it has one generation: no copy of every column.
            self._windows[generation] = window_records(self.recorded, generation)
        return self._windows[generation]

    def window_generations(self) -> list[Generation]:
        """Every generation window of the report, in order, with the System its config_t describes."""
        return [Generation(w.generation, self.system_of(w.generation)) for w in self.report.windows]

    def windows(self) -> Iterator[tuple[Generation, Any, Any]]:
        """(generation, records, inputs) of every generation window of the report, in order: every
        cycle of the run but those of a generation no config names (counted as malformed)."""
        for generation in self.window_generations():
            yield (generation, *self.window(generation.number))

    @property
    def records(self) -> Any:
        """The records of the report's generation (`window`); `windows` has every generation's."""
        return self.window(self.report.generation)[0]

    @property
    def inputs(self) -> Any:
        """Their input records; "record" indexes `records`."""
        return self.window(self.report.generation)[1]

    def to_utc_ns(self, dpu: np.ndarray | int, mono_ns: np.ndarray | int) -> np.ndarray:
        """Wall-clock ns (UTC) of DPU monotonic times (of a DPU with no offset known: unchanged)."""
        # Looked up by DPU id, an int16 as every message holds it: 10^7 records' times took
        # 0.44-0.82 s to map by searching the known ids, 0.09-0.10 s so (the export maps three).
        # The table's last entry, 0, is for an id no int16 holds (none from a log).
        table = np.zeros((1 << 16) + 1, dtype=np.int64)
        for d, value in self.utc_offset_ns.items():
            table[d + (1 << 15)] = value
        ids = np.asarray(dpu)
        if ids.dtype == np.int16:  # the records' ids: every one in the table
            at = ids.astype(np.int32) + (1 << 15)
        else:  # any other integers (one id, a list): widened first, so that the bias cannot wrap
            wide = ids.astype(np.int64)
            at = np.where((wide >= -(1 << 15)) & (wide < 1 << 15), wide + (1 << 15), 1 << 16)
        return np.asarray(mono_ns, dtype=np.int64) + table[at]

    def add_prediction(self, predictor: Predictor) -> str | None:
        """Lays the prediction of the report generation's system file (the one its config_t
        carries) beside the report's figures, as report.predicted; None, or why there is none."""
        system = self.system
        if not system.source_text:
            return "no prediction: the run's configuration carries no system file"
        try:
            prediction = predictor(system.source_text)
        except ValueError as e:
            return f"no prediction: {e}"
        rep = self.report
        rep.predicted = beside(prediction, rep.generation, system.run.late_pct, rep.dpus, rep.processes,
                               rep.chains, rep.faults, rep.buffers)
        if rep.simulated and rep.predicted.cause.startswith(PLATFORM):
            rep.predicted.cause = SIMPLIFIED + rep.predicted.cause[len(PLATFORM):]
        measured = {p.name: p.compute_mean_us for p in rep.processes}
        coded = [f"{p.name}: {_us(measured.get(p.name))} a call, {p.compute_us:g} µs assumed"
                 for p in system.processes if p.code is not None]
        if coded:  # the prediction assumes their compute_us; the run measured their code
            rep.predicted.cause += f"; {REAL_CODE} ({'; '.join(coded)})"
        return None

    def add_simulation(self, simulated: RunReport, where: str) -> None:
        """Lays a simulated run of the same system (its report) beside this measured one, as
        report.simulation: per DPU, what the platform cost."""
        self.report.simulation = simulation_beside(self.report.dpus, simulated.dpus, where)

    def process_names(self) -> dict[int, str]:
        """The report generation's: process id -> name."""
        return process_names(self.system)

    # The tables of the public API (skeleton/__init__.py) and of `skel export --parquet`.
    @cached_property
    def _report_tables(self) -> dict[str, Table]:
        return report_tables(self)

    @property
    def dpus(self) -> Table:
        return self._report_tables["dpus"]

    @property
    def processes(self) -> Table:
        return self._report_tables["processes"]

    @cached_property
    def timing(self) -> Table:
        return timing_table(self)

    @cached_property
    def receptions(self) -> Table:
        return receptions_table(self)

    @property
    def faults(self) -> Table:
        return faults_table(self)

    def tables(self) -> dict[str, Table]:
        """Every table of the run, by name (the Parquet files' names)."""
        return {**self._report_tables, "timing": self.timing, "receptions": self.receptions,
                "faults": self.faults}


def load_run(path: str | os.PathLike[str], run_id: int | None = None,
             key: bytes | None = None) -> RunAnalysis:
    """A run (default: the last with timing records) of an .lcm log, a run directory (its
    run.lcm) or an MCAP from `skel export`. Raises LogError (one line for the user) when
    the file cannot be analysed. With the `key` of a signed run, only its genuine messages
    are analysed (analysis/read/seal.py). A view that needs every record (an export, plots)
    reads them again (`RunAnalysis.recorded`): the report in parts and that second read
    took less time and memory than the analysis of a long run whole."""
    return analyze_log(open_run_log(path), run_id, key)


# A run of more records than this is reported a few DPUs at a time, each part's records let go
# before the next's are read (report.run_part): 10^7 records held at once took 4 GB.
PART_RECORDS = 1 << 21


def analyze_log(log: Log, run_id: int | None = None, key: bytes | None = None,
                part_records: int | None = PART_RECORDS) -> RunAnalysis:
    if log.size == 0:
        raise LogError("empty file")
    if len(log) == 0:
        raise LogError("not an LCM log (no event found)")
    try:
        log, _ = authenticate(log, key)
    except KeyFileError as e:
        raise LogError(str(e)) from e
    heads = timing_heads(log)
    runs = run_ids(log, heads)
    if not runs:
        raise LogError(f"no timing records (channel {TIMING_CHANNEL}) in this log")
    if run_id is None:
        run_id = log.run_id if log.run_id in runs else runs[-1]
    elif run_id not in runs:
        raise LogError(f"no timing records for run {run_id} (runs in this log: {', '.join(map(str, runs))})")
    # The generations are known from the batches' headers, before any record is decoded.
    ok, head = heads
    in_run = ok & (head["run_id"] == run_id)
    generations = set(head["generation"][in_run].tolist())
    expected = published_batches(log, run_id)
    groups = dpu_groups(head["dpu"][in_run], head["n"][in_run], expected, part_records)
    # The control messages decode beside the first part's records (0.3 s of 10^7 records' log,
    # most of it the statuses' pages read in).
    with ThreadPoolExecutor(1) as pool:
        pending = pool.submit(_control, log, generations)
        # a run read in parts: one bound for every part (a run read whole: its records' own)
        usual = run_usual_sizes(log, run_id, heads) if len(groups) > 1 else None
        read_first = [load_records(log, run_id, expected, heads, groups[0], usual)]
        messages, beats, offsets, locking = pending.result()
    candidates = sorted(g for g in generations if g in messages.configs)
    if not candidates:
        raise LogError(f"no config_t (channel {CONFIG_CHANNEL}) for generation {max(generations)}: "
                       "cannot name anything")
    configs = {g: messages.configs[g] for g in candidates}
    windows = report_generations(configs[candidates[-1]], candidates, configs)
    clock = ClockOffsets.from_messages(messages.clock_offsets)

    def read(groups: list[list[int]],
             ready: list[RunRecords]) -> tuple[list[RunPart], int, RunRecords | None]:
        """The parts of `groups` (`ready`: the first one's records when read already, taken out of
        it, so that nothing else holds them), the records of no config's generation, and the
        run's records when it is one part."""
        parts, unnamed, run = [], 0, None
        for dpus in groups:
            run = ready.pop() if ready else load_records(log, run_id, expected, heads, dpus, usual)
            parts.append(run_part(run, windows, set(dpus), clock))
            if generations - set(candidates):
                unnamed += int(np.count_nonzero(~np.isin(run.records["generation"], candidates)))
            timed = set(np.unique(run.records["dpu"]).tolist())
            offsets.update(_offsets_from_batches(log, run, timed - set(offsets), heads))
            if len(groups) > 1:
                run = None  # a part's records are let go before the next one's are read
        return parts, unnamed, run

    parts, unnamed, held = read(groups, read_first)
    if len(parts) > 1 and not holds_its_processes(parts, windows):
        # A process's records in another DPU's batches (a stray DPU, one that took over its
        # processes): its rows are made from every part of it at once, as one part.
        parts, unnamed, held = read([[d for group in groups for d in group]], [])
    log.release()  # every message needed is decoded: the log's pages are given back (Log.release)
    # the batches whose header could not be read, whose DPU is unknown, are in no part
    malformed = {TIMING_CHANNEL: sum(p.counts.malformed for p in parts) + int(np.count_nonzero(~ok)),
                 IMPOSSIBLE: sum(p.counts.impossible for p in parts), **messages.malformed}
    if unnamed:
        # A window without its config cannot be named (a stray batch, or the config was
        # never logged): only the others are reported, and the stray ones are counted.
        malformed[NO_CONFIG] = unnamed
    if not any(part.counts.generations for part in parts):
        raise LogError(f"no timing record of run {run_id} could be decoded")
    report = finish_report(windows, parts, beats, locking, messages.reports, log.integrity, malformed, clock,
                           messages.commands, last_always=False)
    report.simulated = any(c.sender == SIMULATED_SENDER for c in configs.values())
    analysis = RunAnalysis(log=log, heads=heads, messages=messages, report=report, clock=clock,
                           utc_offset_ns=offsets, held=held, usual=usual)
    analysis._systems.update((g.number, g.system) for g in windows)  # each read from its config once
    return analysis


def _control(log: Log, generations: set[int]) -> tuple[Messages, Heartbeats, dict[int, int], list[Any]]:
    """The log's control-plane messages, and what the report needs of their statuses: the
    heartbeats, each DPU's clock offset to UTC, and the statuses that name lockouts. The
    statuses are decoded whole only by the export (lcmjson.to_json_many)."""
    messages = read_messages(log, generations)
    statuses = messages.status_columns(*HEARTBEAT_FIELDS, "utc_ns")
    known = np.ones(len(statuses.heard_us), dtype=bool)
    beats = heartbeats(known, statuses.heard_us, statuses.fields)
    offsets = status_offsets(*(statuses.fields[name] for name in ("dpu", "mono_ns", "utc_ns")))
    return messages, beats, offsets, statuses.locking


def dpu_groups(dpu: np.ndarray, count: np.ndarray, expected: Mapping[int, int],
               most: int | None) -> list[list[int]]:
    """The run's DPUs (`dpu`, `count`: each batch's DPU and record count; `expected`: the DPUs of
    its reports) in groups of consecutive ids of at most `most` records each, as far as one
    DPU's records allow: the parts a run's report is made of, one at a time. One group for a run
    of `most` records or fewer, or when `most` is None."""
    ids = sorted(set(np.unique(dpu).tolist()) | set(expected))
    totals = np.bincount(np.searchsorted(ids, dpu), weights=count, minlength=len(ids)) if len(ids) else []
    groups: list[list[int]] = [[]]
    held = 0
    for d, n in zip(ids, np.asarray(totals, dtype=np.int64).tolist(), strict=True):
        if groups[-1] and most is not None and held + n > most:
            groups.append([])
            held = 0
        groups[-1].append(d)
        held += n
    return groups


def status_offsets(dpu: np.ndarray, mono_ns: np.ndarray, utc_ns: np.ndarray) -> dict[int, int]:
    """dpu -> utc_ns - mono_ns from the statuses' columns (see the module comment)."""
    both = (mono_ns > 0) & (utc_ns > 0)
    return {d: int(np.median((utc_ns - mono_ns)[both & (dpu == d)])) for d in np.unique(dpu[both]).tolist()}


def _offsets_from_batches(log: Log, run: RunRecords, dpus: set[int], heads: Heads) -> dict[int, int]:
    ok, head = heads
    logged_ns = log.utime_us[log.indices(TIMING_CHANNEL)] * 1000
    out: dict[int, int] = {}
    recs = run.records
    for dpu in sorted(dpus):
        mine = recs[recs["dpu"] == dpu]
        latest = {}
        for seq, start in zip(mine["batch_seq"].tolist(), mine["start_ns"].tolist(), strict=True):
            latest[seq] = max(latest.get(seq, start), start)
        sel = ok & (head["dpu"] == dpu) & (head["run_id"] == run.run_id)
        bounds = [
            int(t) - latest[s]
            for s, t in zip(head["batch_seq"][sel].tolist(), logged_ns[sel].tolist(), strict=True)
            if s in latest
        ]
        if bounds:
            out[dpu] = min(bounds)
    return out


def _us(value: float | None) -> str:
    return "not measured" if value is None else f"{value:.1f} µs"
