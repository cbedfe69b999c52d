"""`skel export RUN --trace FILE.json`: the run's timeline as a Chrome / Perfetto trace.

Trace Event Format (JSON), which ui.perfetto.dev and chrome://tracing open: one track
group per DPU ("pid") and one track per process on it ("tid"). Every cycle that ran, in
every generation window, is four complete events ("ph": "X"), one per phase: comm in,
blocked, compute, comm out. An overrun is an instant event at its cycle's end (category
"overrun"); every fault of the report (its generation's) is an instant event (category
"fault", named by its kind) at when it happened, on its DPU's track group (or the whole
trace's when it has no DPU). Times are microseconds on the host's clock: each DPU's
monotonic clock mapped through the clock-offset estimates the report uses (identity on
one machine).
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import asdict
from typing import Any

import numpy as np

from ..measure.faults import first_release_ns
from ..measure.run import RunAnalysis
from ..read.records import FLAG_OVERRUN, FLAG_RELEASE_SKIPPED, FLAG_SKIPPED
from .outfile import replaced

# (event name, the record's duration field), in the order a cycle runs them.
PHASES = (("comm in", "comm_in_ns"), ("blocked", "blocked_ns"), ("compute", "compute_ns"),
          ("comm out", "comm_out_ns"))  # fmt: skip
CATEGORY = "cycle"


def write_trace(run: RunAnalysis, path: str | os.PathLike[str]) -> int:
    """Write the trace; returns how many events it holds."""
    events = list(_metadata(run)) + list(_phases(run)) + list(_faults(run))
    trace = {"traceEvents": events, "displayTimeUnit": "ms",
             "otherData": {"system": run.report.system, "run_id": run.report.run_id,
                           "generation": run.report.generation,
                           "generations": run.report.generations}}  # fmt: skip
    with replaced(path) as part:
        part.write_text(json.dumps(trace, separators=(",", ":")), encoding="utf-8")
    return len(events)


def _host_us(run: RunAnalysis, dpus: np.ndarray, t_ns: np.ndarray) -> np.ndarray:
    return run.clock.to_host_many(dpus, t_ns) / 1e3


def _metadata(run: RunAnalysis) -> Iterator[dict[str, Any]]:
    # Every generation's DPUs and processes, since every window's cycles are on the tracks:
    # a process a push moved or removed keeps its track, named as its last config names it.
    hosts: dict[int, str] = {}
    threads: dict[tuple[int, int], str] = {}
    for generation in run.window_generations():
        hosts.update((d.id, d.host) for d in generation.system.dpus)
        threads.update(((p.dpu, p.id), p.name) for p in generation.system.processes)
    for dpu in sorted(hosts):
        yield {"ph": "M", "name": "process_name", "pid": dpu, "args": {"name": f"DPU {dpu} ({hosts[dpu]})"}}
        yield {"ph": "M", "name": "process_sort_index", "pid": dpu, "args": {"sort_index": dpu}}
    for (dpu, pid), name in threads.items():
        yield {"ph": "M", "name": "thread_name", "pid": dpu, "tid": pid, "args": {"name": name}}


def _phases(run: RunAnalysis) -> Iterator[dict[str, Any]]:
    for _, recs, _ in run.windows():
        yield from _cycles(run, recs)


def _cycles(run: RunAnalysis, recs: Any) -> Iterator[dict[str, Any]]:
    """The phases and overruns of one window's cycles that ran."""
    ran = (np.asarray(recs["flags"]).astype(np.int64) & (FLAG_SKIPPED | FLAG_RELEASE_SKIPPED)) == 0
    recs = recs[ran]
    dpus = np.asarray(recs["dpu"])
    at = np.asarray(recs["start_ns"]).copy()
    cols = {k: recs[k].tolist() for k in ("dpu", "process", "cycle", "flags")}
    for name, field in PHASES:
        length = np.asarray(recs[field])
        start_us = _host_us(run, dpus, at).tolist()
        for i, dur in enumerate((length / 1e3).tolist()):
            yield {"ph": "X", "cat": CATEGORY, "name": name, "pid": cols["dpu"][i], "tid": cols["process"][i],
                   "ts": start_us[i], "dur": dur, "args": {"cycle": cols["cycle"][i]}}  # fmt: skip
        at = at + length
    end_us = _host_us(run, dpus, at).tolist()
    for i in np.flatnonzero(np.asarray(recs["flags"]).astype(np.int64) & FLAG_OVERRUN).tolist():
        yield {"ph": "i", "s": "t", "cat": "overrun", "name": "overrun", "pid": cols["dpu"][i],
               "tid": cols["process"][i], "ts": end_us[i], "args": {"cycle": cols["cycle"][i]}}  # fmt: skip


def _faults(run: RunAnalysis) -> Iterator[dict[str, Any]]:
    """The report's faults (its generation's), where they happened: their at_s and cycles count
    from the run's first release (of their DPU; a stall's, of the first DPU's)."""
    origin = first_release_ns(run.recorded.records)
    system = run.system
    start = min(origin.values(), default=0)
    for fault in run.report.faults:
        proc = system.find_process(fault.process) if fault.process else None
        dpu = fault.dpu if fault.dpu is not None else proc.dpu if proc is not None else None
        t0 = origin.get(dpu, start) if dpu is not None and fault.kind != "stall" else start
        if fault.at_s is not None:
            t_ns = t0 + int(fault.at_s * 1e9)
        elif proc is not None and fault.cycle is not None:
            t_ns = t0 + fault.cycle * proc.period_us * 1000
        else:
            t_ns = t0
        event = {"ph": "i", "cat": "fault", "name": fault.kind, "args": asdict(fault),
                 "ts": float(_host_us(run, np.array([dpu or 0]), np.array([t_ns]))[0])}  # fmt: skip
        if dpu is None:
            event.update(s="g", pid=0)
        else:
            event.update(s="p", pid=dpu)
        yield event
