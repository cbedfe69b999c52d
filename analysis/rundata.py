"""Everything plots and exports need about one run, from an LCM log or an MCAP export.

`load_run_data(path, run_id)` returns the report (the same `analyze_log` as `skel
report`), the config_t of its generation, the records of that generation, the
DPUs' status messages, and a map from each DPU's monotonic clock to wall-clock time.

Wall clock: timing records are stamped with the DPU's CLOCK_MONOTONIC, which means
nothing outside the DPU. Each status_t carries a (mono_ns, utc_ns) pair read at one
instant, so utc - mono is that DPU's offset; the median over its status messages is
robust to a stalled heartbeat. A DPU with no status message falls back to its timing
batches: a batch is logged after every record in it started, so
min(logged utime - latest start) bounds the offset from above (by the batching delay).
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

import numpy as np

import skelmsg

from .flatdecode import decode_heads
from .latency import ClockOffsets
from .logreader import Log
from .records import TIMING, TIMING_CHANNEL, RunRecords, load_run
from .report import (
    CLOCK_CHANNEL,
    CONFIG_CHANNEL,
    REPORT_CHANNEL,
    STATUS_CHANNEL,
    LogError,
    RunReport,
    analyze_log,
    read_run_log,
)


@dataclass
class RunData:
    log: Log
    report: RunReport
    config: Any  # config_t of the report's generation
    run: RunRecords  # every generation of the run
    records: np.ndarray  # the report's generation only
    inputs: np.ndarray  # their input records ("record" indexes `records`)
    statuses: list[Any]  # every decodable status_t in the log, in log order
    utc_offset_ns: dict[int, int]  # dpu -> utc_ns - mono_ns
    clock: ClockOffsets  # DPU clock -> host clock (SKEL_CLOCK estimates), as the report uses

    def to_utc_ns(self, dpu: np.ndarray | int, mono_ns: np.ndarray | int) -> np.ndarray:
        """Wall-clock ns (UTC) of DPU monotonic times."""
        dpus = np.asarray(dpu)
        offsets = np.vectorize(lambda d: self.utc_offset_ns.get(int(d), 0), otypes=[np.int64])(dpus)
        return np.asarray(mono_ns, dtype=np.int64) + offsets

    def process_names(self) -> dict[int, str]:
        return {p.id: p.name for p in self.config.processes}


def load_run_data(path: str | os.PathLike[str], run_id: int | None = None) -> RunData:
    """Raises LogError (one line for the user) when the file cannot be analysed."""
    return run_data(read_run_log(path), run_id)


def run_data(log: Log, run_id: int | None = None) -> RunData:
    report = analyze_log(log, run_id)
    reports = _decode(log, REPORT_CHANNEL, skelmsg.report_t)
    expected = {r.dpu: r.timing_batches for r in reports if r.run_id == report.run_id}
    run = load_run(log, report.run_id, expected_batches=expected)
    config = config_of(log, report.generation)
    keep = np.flatnonzero(run.records["generation"] == report.generation)
    inputs = run.inputs[np.isin(run.inputs["record"], keep)].copy()
    inputs["record"] = np.searchsorted(keep, inputs["record"])
    statuses = _decode(log, STATUS_CHANNEL, skelmsg.status_t)
    return RunData(
        log=log,
        report=report,
        config=config,
        run=run,
        records=run.records[keep],
        inputs=inputs,
        statuses=statuses,
        utc_offset_ns=utc_offsets(log, run, statuses),
        clock=ClockOffsets.from_messages(_decode(log, CLOCK_CHANNEL, skelmsg.clock_offset_t)),
    )


def config_of(log: Log, generation: int) -> Any:
    """The last decodable config_t of a generation (analyze_log found it already)."""
    for _, data in reversed(log.messages(CONFIG_CHANNEL)):
        try:
            config = skelmsg.config_t.decode(bytes(data))
        except Exception:  # malformed: analyze_log counted it
            continue
        if config.generation == generation:
            return config
    raise LogError(f"no config_t for generation {generation}")


def _decode(log: Log, channel: str, cls: type) -> list[Any]:
    out = []
    for _, data in log.messages(channel):
        try:
            out.append(cls.decode(bytes(data)))  # type: ignore[attr-defined]
        except Exception:  # malformed: counted by analyze_log, skipped here
            continue
    return out


def utc_offsets(log: Log, run: RunRecords, statuses: list[Any]) -> dict[int, int]:
    """dpu -> utc_ns - mono_ns, for every DPU with records (see the module comment)."""
    offsets: dict[int, int] = {}
    for dpu in sorted({s.dpu for s in statuses}):
        mine = [s for s in statuses if s.dpu == dpu and s.mono_ns > 0 and s.utc_ns > 0]
        if mine:
            offsets[dpu] = int(np.median([s.utc_ns - s.mono_ns for s in mine]))
    missing = set(np.unique(run.records["dpu"]).tolist()) - set(offsets)
    if missing:
        offsets.update(_offsets_from_batches(log, run, missing))
    return offsets


def _offsets_from_batches(log: Log, run: RunRecords, dpus: set[int]) -> dict[int, int]:
    idx = log.indices(TIMING_CHANNEL)
    ok, heads = decode_heads(TIMING, log.buf, log.data_offset[idx], log.data_len[idx])
    logged_ns = log.utime_us[idx] * 1000
    out: dict[int, int] = {}
    recs = run.records
    for dpu in sorted(dpus):
        mine = recs[recs["dpu"] == dpu]
        latest = {}
        for seq, start in zip(mine["batch_seq"].tolist(), mine["start_ns"].tolist(), strict=True):
            latest[seq] = max(latest.get(seq, start), start)
        sel = ok & (heads["dpu"] == dpu) & (heads["run_id"] == run.run_id)
        bounds = [
            int(t) - latest[s]
            for s, t in zip(heads["batch_seq"][sel].tolist(), logged_ns[sel].tolist(), strict=True)
            if s in latest
        ]
        if bounds:
            out[dpu] = min(bounds)
    return out
