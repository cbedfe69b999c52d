"""Throughput of analysis/read/logreader.py + records.py against lcm.EventLog with the
generated decoders, on synthetic SERVO-like logs (9 processes on 4 DPUs, 5 ms).

Two logs: "timing" (what a logger restricted to SKEL_TIMING/STATUS/CONFIG holds)
and "full" (also one 256-byte buffer_t per process cycle, as the default logger
records every channel). Both sides produce the same numpy record columns.

Usage: .venv/bin/python bench/logreader_bench.py [records]   (writes bench/results/logreader.txt)
"""

from __future__ import annotations

import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import lcm
import numpy as np

import skelmsg
from skeleton.analysis.read.flatdecode import decode_heads, decode_many
from skeleton.analysis.read.logreader import read_log
from skeleton.analysis.read.records import TIMING, load_records
from skelmsg.contract import STATUS_CHANNEL, TIMING_CHANNEL

RESULTS = Path(__file__).resolve().parent / "results" / "logreader.txt"
SPEEDUP = 10.0  # at least this many times lcm.EventLog to the same columns
BATCH = 64  # records per timing_t batch
# Every per-record array of timing_t (whatever fields it gains).
_T = skelmsg.timing_t
ARRAYS = tuple(name for name, dims in zip(_T.__slots__, _T.__dimensions__, strict=True) if dims == ["n"])
INPUTS = ("in_record", "in_buffer", "in_seq", "in_new", "in_dropped", "in_received",
          "in_sent_ns", "in_recv_ns")  # fmt: skip


def write_log(path: Path, records: int, with_buffers: bool) -> None:
    rng = np.random.default_rng(1)
    log = lcm.EventLog(str(path), "w", overwrite=True)
    buf = skelmsg.buffer_t()
    buf.run_id, buf.nbytes, buf.payload = 1, 256, bytes(256)
    buf_data = buf.encode()
    status = skelmsg.status_t()
    status.host, status.reject_reason, status.run_id = "h", "", 1
    status_data = status.encode()
    utime, seq = 0, {d: 0 for d in range(1, 5)}
    for first in range(0, records, BATCH):
        dpu = 1 + (first // BATCH) % 4
        t = skelmsg.timing_t()
        t.dpu, t.run_id, t.generation, t.batch_seq, t.n = dpu, 1, 1, seq[dpu], BATCH
        seq[dpu] += 1
        for name in ARRAYS:
            small = name in ("flags", "event_queued")  # int8 / int16 fields
            setattr(t, name, rng.integers(0, 10**9, BATCH).tolist() if not small else [0] * BATCH)
        t.process = rng.integers(0, 9, BATCH).tolist()
        # inputs per batch vary with the mix of processes in it (0..5 inputs each)
        t.ninputs = int(rng.integers(BATCH, 3 * BATCH))
        for name in INPUTS:
            setattr(t, name, rng.integers(0, 100 if name != "in_record" else BATCH, t.ninputs).tolist())
        if with_buffers:
            for i in range(BATCH):
                log.write_event(utime, f"SKEL_BUF_{i % 9}", buf_data)
                utime += 555
        log.write_event(utime, TIMING_CHANNEL, t.encode())
        if first % (BATCH * 16) == 0:
            log.write_event(utime, STATUS_CHANNEL, status_data)
    log.close()


def ours(path: Path) -> dict[str, np.ndarray]:
    """Up to records.RunRecords: the record and input tables the metrics take, every
    column of both in hand (not only the two compared)."""
    run = load_records(read_log(path))
    columns = [table[name] for table in (run.records, run.inputs) for name in table.names]
    assert all(isinstance(c, np.ndarray) for c in columns)
    return {"start_ns": run.records["start_ns"], "in_seq": run.inputs["seq"]}


def ours_columns(path: Path) -> dict[str, np.ndarray]:
    """Up to the same product as the baseline: every timing column of the run, as numpy."""
    log = read_log(path)
    idx = log.indices(TIMING_CHANNEL)
    starts, lengths = log.data_offset[idx], log.data_len[idx]
    ok, heads = decode_heads(TIMING, log.buf, starts, lengths)
    chosen = np.flatnonzero(ok & (heads["run_id"] == heads["run_id"][ok][-1]))
    dec = decode_many(TIMING, log.buf, starts[chosen], lengths[chosen])
    return {"start_ns": dec.columns["start_ns"], "in_seq": dec.columns["in_seq"]}


COLUMNS = ARRAYS + INPUTS


def baseline(decode_all: bool) -> Callable[[Path], dict[str, np.ndarray]]:
    """lcm.EventLog + the generated decoder per event, then every timing column as
    numpy (what the analysis needs; ours also builds the structured arrays)."""
    types = {STATUS_CHANNEL: skelmsg.status_t, TIMING_CHANNEL: skelmsg.timing_t}

    def run(path: Path) -> dict[str, np.ndarray]:
        cols: dict[str, list[np.ndarray]] = {name: [] for name in COLUMNS}
        for event in lcm.EventLog(str(path)):
            if event.channel == TIMING_CHANNEL:
                t = skelmsg.timing_t.decode(event.data)
                for name in COLUMNS:
                    cols[name].append(np.asarray(getattr(t, name), dtype=np.int64))
            elif decode_all:
                types.get(event.channel, skelmsg.buffer_t).decode(event.data)
        out = {k: np.concatenate(v) for k, v in cols.items()}
        return {"start_ns": out["start_ns"], "in_seq": out["in_seq"]}

    return run


def best_of(fn: Callable[[Path], dict[str, np.ndarray]], path: Path, repeat: int = 3) -> tuple[float, dict]:
    best, out = float("inf"), {}
    for _ in range(repeat):
        t0 = time.perf_counter()
        out = fn(path)
        best = min(best, time.perf_counter() - t0)
    return best, out


def measure(records: int = 500_000) -> list[str]:
    """The headline ("log reader: N.Nx lcm.EventLog ...") and one line per log.

    Two products of ours: the timing columns (what the baseline builds: the same
    work) and records.RunRecords (also the structured arrays the metrics take)."""
    lines = [f"# {records} process-cycle records, {BATCH} per timing_t batch, 1-3 inputs per record; "
             "best of 15 (ours: <0.1 s each, so a noisy neighbour spoils fewer) and 3 (baseline); "
             "baseline = lcm.EventLog + the generated decoder per event "
             "+ numpy columns"]
    headline = ""
    with tempfile.TemporaryDirectory() as tmp:
        for name, with_buffers in (("timing", False), ("full", True)):
            path = Path(tmp) / f"{name}.lcm"
            write_log(path, records, with_buffers)
            t_cols, a = best_of(ours_columns, path, 15)
            t_ours, b = best_of(ours, path, 15)
            t_all, c = best_of(baseline(True), path)
            t_timing, d = best_of(baseline(False), path)
            # RunRecords holds a batch's inputs in its records' order (records.input_starts); this
            # log lists them in any order, as the wire allows: the same values, maybe reordered.
            assert all(np.array_equal(a["start_ns"], other["start_ns"]) for other in (b, c, d))
            assert all(np.array_equal(np.sort(a["in_seq"]), np.sort(other["in_seq"])) for other in (b, c, d))
            events = len(read_log(path))
            per_s = {k: records / t / 1e6 for k, t in (("cols", t_cols), ("ours", t_ours))}
            lines.append(
                f"{name} log: {path.stat().st_size / 1e6:.0f} MB, {events} events; "
                f"ours to columns {t_cols:.3f} s ({per_s['cols']:.1f} M records/s, {t_all / t_cols:.1f}x), "
                f"to RunRecords {t_ours:.3f} s ({per_s['ours']:.1f} M records/s, {t_all / t_ours:.1f}x); "
                f"lcm.EventLog + decode every event {t_all:.3f} s; "
                f"lcm.EventLog + decode timing_t only {t_timing:.3f} s"
            )
            if name == "timing":
                headline = (
                    f"log reader: {t_all / t_cols:.1f}x lcm.EventLog (goal {SPEEDUP:g}x): "
                    f"{'PASS' if t_all / t_cols >= SPEEDUP else 'FAIL'} ({per_s['cols']:.1f} M records/s "
                    f"to the same numpy columns; {t_all / t_ours:.1f}x, {per_s['ours']:.1f} M records/s "
                    "to records.RunRecords)"
                )
    return [headline, *lines]


def main() -> None:
    records = int(sys.argv[1]) if len(sys.argv) > 1 else 500_000
    text = "\n".join(measure(records)) + "\n"
    RESULTS.parent.mkdir(parents=True, exist_ok=True)
    RESULTS.write_text(text)
    print(text, end="")


if __name__ == "__main__":
    main()
