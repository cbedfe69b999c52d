"""A run's measures as tables: what the Python API returns (`run.timing.to_pandas()`)
and `skel export --parquet` writes, one table per file.

Every column is documented once, in COLUMNS below; the Parquet files carry the same
text as field metadata, and the documentation's reference is generated from this list. Names end in
their unit (_ns, _us, _ms, _s, _pct). Times named *_ns are the DPU's CLOCK_MONOTONIC
unless named *_utc_ns (wall clock, from the DPU's status messages).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterator, Mapping, Sequence
from typing import TYPE_CHECKING, Any, Protocol

import numpy as np
import pyarrow as pa

from skeleton.host.model import System

from ..read.records import CYCLE_FIELDS, FLAG_LOCKOUT, FLAG_OVERRUN, FLAG_RELEASE_SKIPPED, FLAG_SKIPPED
from .latency import ClockOffsets
from .metrics import completed, cycle_end_ns, event_latency_us, event_response_us, measured
from .report import RunReport
from .windows import Generation

if TYPE_CHECKING:
    import pandas as pd


class RunAnalysis(Protocol):
    """What the tables need of a run (run.RunAnalysis, which builds its tables from here)."""

    report: RunReport
    clock: ClockOffsets

    def windows(self) -> Iterator[tuple[Generation, Any, Any]]: ...
    def to_utc_ns(self, dpu: np.ndarray | int, mono_ns: np.ndarray | int) -> np.ndarray: ...

_RUN = {
    "run_id": "the run", "generation": "config generation the row belongs to",
}  # fmt: skip
_CYCLE = {
    "dpu": "DPU id", "process": "process id", "process_name": "process name",
    "cycle": "release number of the process, from 0", "minor": "minor cycle of its DPU",
    "release_ns": "when the cycle was released (its period's start)",
    "sched_ns": "when the DPU's schedule meant it to start",
    "start_ns": "when it started", "comm_in_ns": "time reading its inputs (less a stall: in preempted_ns)",
    "blocked_ns": "time waiting for data (sync: data)",
    "asked_ns": "the compute the cycle was to emulate (a draw when it varies), over the DPU's speed",
    "compute_ns": "emulated compute",
    "comm_out_ns": "time publishing its outputs (less a stall: in preempted_ns)",
    "idle_ns": "time waiting for its next release",
    "slack_ns": "time left before its deadline (negative: overrun)",
    "stall_ns": "time the DPU's thread was kept from running (machine stalls)",
    "debt_ns": "cyclic executive: its stalls since it last slept until a release, at the cycle's "
               "start: the part of the lateness the platform explains",
    "preemptions": "times higher-priority work took the processor from it (tasking executive)",
    "preempted_ns": "time it was kept off the processor so, between its start and its end",
    "event_ns": "sync: event: when the event the cycle handled reached its DPU (-1: not an event cycle)",
    "event_queued": "sync: event: events still waiting behind it when it started",
    "event_dropped": "sync: event: events its full queue dropped since its previous cycle",
    "flags": "timing_t flag bits (the booleans below)",
}  # fmt: skip
COLUMNS: dict[str, dict[str, str]] = {
    "timing": {
        **_RUN, **_CYCLE,
        "overrun": "the cycle missed its deadline", "skipped": "the cycle did not run (DPU behind)",
        "lockout": "the process was locked out in this cycle",
        "release_skipped": "a data process a period behind skipped this release",
        "measured": "inside the DPU's measurement window of the row's generation (after warm-up)",
        "completed": "ran to its end (not skipped, not a skipped release): with `measured`, the "
                     "cycles the report's latencies count",
        "release_latency_us": "start - release", "response_us": "end of the cycle's work - release",
        "event_latency_us": "sync: event: start - event (empty for other cycles)",
        "event_response_us": "sync: event: end of the cycle's work - event (empty for other cycles)",
        "start_utc_ns": "start, on the wall clock",
    },
    "receptions": {
        **_RUN, "dpu": "reader's DPU", "process": "reader's process id", "process_name": "reader",
        "cycle": "the reader's cycle", "buffer": "buffer id", "buffer_name": "buffer name",
        "seq": "sequence number of the copy read", "new": "a copy not read before",
        "dropped": "sequences the reader never saw since its last new copy",
        "received": "copies received since the last read",
        "sent_ns": "when the writer sent it (writer's DPU clock)",
        "recv_ns": "when the reader's DPU received it (reader's DPU clock)",
        "transport_us": "recv - sent, corrected by the clock offsets between hosts when estimated",
    },
    "faults": {
        "kind": "lockout, jam, behind, skipping, stall, overrun, dpu_lost or delivery",
        "process": "the process concerned", "dpu": "its DPU", "buffer": "the buffer concerned",
        "writer": "the buffer's writer", "cycle": "when (the process's cycle)",
        "chain": "jam: head ... root cause", "detail": "the fault in words",
        "count": "overrun: how many", "static_load_pct": "jam: static load of the root cause's DPU",
        "root_dpu": "jam: DPU of the chain's last process", "host": "stall: the host",
        "dpus": "stall: the DPUs that stalled together",
        "at_s": "when, s from the run's first release", "duration_ms": "how long",
        "behind_ms": "behind: the largest lateness", "fatal": "the design's flaw (exit 3)",
    },
}  # fmt: skip
# dpus, processes, buffers, chains: the rows of report.json, nested fields joined with "_"
# (release_latency_us_p99); their columns are report.json's (the documentation's reference).
REPORT_TABLES = ("dpus", "processes", "buffers", "chains")
# A list of rows inside a report row is a table of its own, keyed by its parent's name:
# table -> (field, the child table's name, parent column, its name in the child).
CHILD_TABLES = {
    "processes": ("inputs", "process_inputs", "name", "process"),
    "buffers": ("readers", "buffer_readers", "buffer", "buffer"),
}


class Table:
    """Columns of equal length, as pyarrow holds them: `to_arrow()`, `to_pandas()`."""

    def __init__(self, name: str, table: pa.Table) -> None:
        self.name = name
        self._table = table

    def to_arrow(self) -> pa.Table:
        return self._table

    def to_pandas(self) -> pd.DataFrame:
        return self._table.to_pandas()

    @property
    def columns(self) -> list[str]:
        return list(self._table.column_names)

    def __len__(self) -> int:
        return self._table.num_rows

    def __repr__(self) -> str:
        return f"<Table {self.name}: {len(self)} rows x {len(self.columns)} columns>"


def _documented(name: str, columns: Mapping[str, Any]) -> Table:
    docs = COLUMNS.get(name, {})
    fields, arrays = [], []
    for column, values in columns.items():
        array = pa.array(values)
        meta = {"description": docs[column]} if column in docs else None
        fields.append(pa.field(column, array.type, metadata=meta))
        arrays.append(array)
    return Table(name, pa.Table.from_arrays(arrays, schema=pa.schema(fields)))


def _joined(name: str, windows: Sequence[Mapping[str, Any]]) -> Table:
    """One table of every generation window's columns, window after window."""
    if len(windows) == 1:  # the run's one generation: its columns as they are, no concatenation
        return _documented(name, windows[0])
    # An empty window's name columns are of type null: promoted to the others' string.
    return Table(name, pa.concat_tables([_documented(name, w).to_arrow() for w in windows],
                                        promote_options="default"))


def timing_table(run: RunAnalysis) -> Table:
    """Every cycle of every generation window, each measured and named by its own window's
    config (its warm-up and periods decide `measured`, as in that window's report)."""
    return _joined("timing", [_timing_columns(run, gen, recs) for gen, recs, _ in run.windows()])


def _timing_columns(run: RunAnalysis, generation: Generation, recs: Any) -> dict[str, Any]:
    names = process_names(generation.system)
    flags = np.asarray(recs["flags"]).astype(np.int64)
    start = np.asarray(recs["start_ns"])
    release = np.asarray(recs["release_ns"])
    n = len(recs)
    return {
        "run_id": np.full(n, run.report.run_id, dtype=np.int64),
        "generation": np.asarray(recs["generation"]),
        "dpu": np.asarray(recs["dpu"]), "process": np.asarray(recs["process"]),
        "process_name": [names.get(int(p), "") for p in recs["process"].tolist()],
        **{f: np.asarray(recs[f], dtype=np.int64) for f in CYCLE_FIELDS}, "flags": flags.astype(np.int8),
        "overrun": (flags & FLAG_OVERRUN) != 0, "skipped": (flags & FLAG_SKIPPED) != 0,
        "lockout": (flags & FLAG_LOCKOUT) != 0, "release_skipped": (flags & FLAG_RELEASE_SKIPPED) != 0,
        "measured": measured(recs, generation.system),
        "completed": completed(recs) if n else np.zeros(0, dtype=bool),
        "release_latency_us": (start - release) / 1e3,
        "response_us": (cycle_end_ns(recs) - release) / 1e3 if n else np.zeros(0),
        "event_latency_us": event_latency_us(recs) if n else np.zeros(0),
        "event_response_us": event_response_us(recs) if n else np.zeros(0),
        "start_utc_ns": run.to_utc_ns(np.asarray(recs["dpu"]), start) if n else np.zeros(0, np.int64),
    }  # fmt: skip


def process_names(system: System) -> dict[int, str]:
    """process id -> name, for naming every row of a table at once."""
    return {p.id: p.name for p in system.processes}


def receptions_table(run: RunAnalysis) -> Table:
    """Every input read in every generation window, named by its own window's config."""
    return _joined("receptions", [_reception_columns(run, gen, ins) for gen, _, ins in run.windows()])


def _reception_columns(run: RunAnalysis, generation: Generation, ins: Any) -> dict[str, Any]:
    system = generation.system
    names = process_names(system)
    buffers = {b.id: b.name for b in system.buffers}   # per row below: one dict, not a lookup each
    writer_dpu = {b.id: w.dpu if (w := system.find_process(b.writer)) is not None else None
                  for b in system.buffers}
    sent = np.asarray(ins["sent_ns"])
    recv = np.asarray(ins["recv_ns"])
    transport = recv - sent
    # Each DPU's clock mapped to the host's (SKEL_CLOCK estimates), as the report's latencies are.
    for reader in np.unique(ins["dpu"]).tolist():
        for buffer in np.unique(ins["buffer"][ins["dpu"] == reader]).tolist():
            sel = (ins["dpu"] == reader) & (ins["buffer"] == buffer)
            writer = writer_dpu.get(int(buffer))
            if writer is None or writer == reader:
                continue
            transport[sel] = (run.clock.to_host(int(reader), recv[sel])
                              - run.clock.to_host(writer, sent[sel]))
    n = len(ins)
    return {
        "run_id": np.full(n, run.report.run_id, dtype=np.int64),
        "generation": np.full(n, generation.number, dtype=np.int64),
        "dpu": np.asarray(ins["dpu"]), "process": np.asarray(ins["process"]),
        "process_name": [names.get(int(p), "") for p in ins["process"].tolist()],
        "cycle": np.asarray(ins["cycle"]), "buffer": np.asarray(ins["buffer"]),
        "buffer_name": [buffers.get(int(b), "") for b in ins["buffer"].tolist()],
        "seq": np.asarray(ins["seq"]), "new": np.asarray(ins["new"]) != 0,
        "dropped": np.asarray(ins["dropped"]), "received": np.asarray(ins["received"]),
        "sent_ns": sent, "recv_ns": recv, "transport_us": transport / 1e3,
    }  # fmt: skip


def faults_table(run: RunAnalysis) -> Table:
    rows = [dataclasses.asdict(f) for f in run.report.faults]
    if not rows:
        return _documented("faults", _empty_faults())
    return _documented("faults", {c: [r[c] for r in rows] for c in COLUMNS["faults"]})


def _empty_faults() -> dict[str, pa.Array]:
    types = {"chain": pa.list_(pa.string()), "dpus": pa.list_(pa.int64()), "fatal": pa.bool_(),
             "detail": pa.string(), "kind": pa.string()}
    return {c: pa.array([], type=types.get(c, pa.null())) for c in COLUMNS["faults"]}


def report_tables(run: RunAnalysis) -> dict[str, Table]:
    """REPORT_TABLES and their CHILD_TABLES: the rows report.json holds, flattened."""
    report = run.report.to_json()
    out = {}
    for name in REPORT_TABLES:
        rows = report[name]
        child = CHILD_TABLES.get(name)
        if child is not None:
            field, child_name, parent, as_name = child
            out[child_name] = _rows_table(child_name, [{as_name: row[parent], **_flat(c)} for row in rows
                                                        for c in row[field]])
            rows = [{k: v for k, v in row.items() if k != field} for row in rows]
        out[name] = _rows_table(name, [_flat(row) for row in rows])
    return out


def _rows_table(name: str, rows: list[dict[str, Any]]) -> Table:
    keys: dict[str, None] = {}
    for row in rows:
        keys.update(dict.fromkeys(row))
    return _documented(name, {k: [r.get(k) for r in rows] for k in keys})


def _flat(row: Mapping[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for key, value in row.items():
        if isinstance(value, Mapping):
            if {"bins", "counts"} <= set(value):
                continue  # a histogram: a plot's data, not a column
            out.update(_flat(value, f"{prefix}{key}_"))
        else:
            out[f"{prefix}{key}"] = value
    return out
