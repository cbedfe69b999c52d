"""`skel export RUN.lcm RUN.mcap`: one run as an MCAP file Foxglove can open.

Topics:

  /timing/<dpu>/<process>   one message per process cycle (its timing_t record and its
                            inputs), ROS 2 CDR with a ros2msg schema: binary, so that
                            millions are written at numpy speed (mcapbulk.py)
  /dpu/<id>/status          status_t          /dpu/<id>/report   report_t
  /dpu/<id>/clock_offset    clock_offset_t    /config            config_t (every generation)
  /command                  command_t         /faults            the report's faults

MCAP has no LCM encoding and Foxglove cannot decode LCM: the control messages (few) are
JSON with a JSON Schema derived from the generated types (lcmjson.py).

Times: a timing message's log_time is the cycle's start mapped to wall clock (see
measure/run.py: per-DPU utc - mono offset from status_t), publish_time its release,
sequence its cycle number; every other message's log_time is the lcm-logger receive
time. The source log is attached whole as run.lcm (mcapformat.SOURCE_LOG), byte for
byte with its seals and any damage, so `skel report RUN.mcap` reads exactly what
`skel report RUN.lcm` reads. The system file is attached as system.yaml; metadata
"skeleton" holds the system name, run id, generation and the source log's integrity.
"""

from __future__ import annotations

import json
import os
from collections.abc import Iterator
from dataclasses import asdict
from typing import Any

import numpy as np

import skelmsg
from skelmsg import contract
from skelmsg.contract import TIMING_CHANNEL

from ..measure.faults import KINDS
from ..measure.metrics import cycle_end_ns
from ..measure.run import RunAnalysis
from ..read.lcmjson import schema_of, to_json_many, type_name
from ..read.mcapformat import FAULTS_TOPIC, METADATA, SOURCE_LOG, TIMING_PREFIX
from ..read.records import CYCLE_FIELDS, FLAG_LOCKOUT, FLAG_OVERRUN, FLAG_SKIPPED, concat_ranges, input_starts
from .mcapbulk import BulkWriter, MessageSource, scatter
from .outfile import DropBehindFile, replaced

# LCM channel -> (type, topic prefix); the DPU id completes per-DPU topics.
MESSAGE_CHANNELS: dict[str, tuple[type, str]] = {
    contract.CONFIG_CHANNEL: (skelmsg.config_t, "/config"),
    contract.COMMAND_CHANNEL: (skelmsg.command_t, "/command"),
    contract.STATUS_CHANNEL: (skelmsg.status_t, "/dpu/{dpu}/status"),
    contract.REPORT_CHANNEL: (skelmsg.report_t, "/dpu/{dpu}/report"),
    contract.CLOCK_CHANNEL: (skelmsg.clock_offset_t, "/dpu/{dpu}/clock_offset"),
}

# A timing message, field by field: every integer an int64 and every float a float64,
# so each lands 8-aligned and a whole chunk of them is one numpy structured array.
RECORD_INTS = ("run_id", "dpu", "process", "generation", "batch_seq", "index", "logged_us",
               *CYCLE_FIELDS, "flags")  # fmt: skip
RECORD_FLOATS = ("release_latency_us", "response_us")
RECORD_BOOLS = ("overrun", "skipped", "lockout")
INPUT_INTS = ("buffer", "seq", "new", "dropped", "received", "sent_ns", "recv_ns")
INPUT_FLOATS = ("transport_us",)
# XCDR1 little endian: a 4-byte encapsulation header, then each field aligned to its own
# size from the end of that header; the input count (uint32) falls 4-aligned after the
# bools and one pad byte, and leaves the first input 8-aligned.
TIMING_CDR = np.dtype(
    [("encapsulation", "V4")] + [(k, "<i8") for k in RECORD_INTS] + [(k, "<f8") for k in RECORD_FLOATS]
    + [(k, "u1") for k in RECORD_BOOLS] + [("pad", "u1"), ("ninputs", "<u4")]
)
INPUT_CDR = np.dtype([(k, "<i8") for k in INPUT_INTS] + [(k, "<f8") for k in INPUT_FLOATS])
CDR_LE = b"\x00\x01\x00\x00"
if (TIMING_CDR.itemsize - 4) % 8 or INPUT_CDR.itemsize % 8:
    raise ImportError("the timing CDR layout lost its alignment: keep 8-byte fields first")
_SEP = "=" * 80
TIMING_SCHEMA = "\n".join(
    ["# One process cycle (a timing_t record) with its input records. Times in ns of the DPU's",
     "# CLOCK_MONOTONIC; index: the record's position in its timing_t batch; logged_us: when",
     "# the logger heard that batch. The topic names the DPU and the process; the channel's",
     "# metadata maps buffer ids to names."]
    + [f"int64 {k}" for k in RECORD_INTS] + [f"float64 {k}" for k in RECORD_FLOATS]
    + [f"bool {k}" for k in RECORD_BOOLS]
    + ["skeleton/TimingInput[] inputs", _SEP, "MSG: skeleton/TimingInput"]
    + [f"int64 {k}" for k in INPUT_INTS] + [f"float64 {k}" for k in INPUT_FLOATS]
) + "\n"
_OPT_STR = {"type": ["string", "null"]}
_OPT_INT = {"type": ["integer", "null"]}
FAULT_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "skeleton.fault",
    "description": "A fatal flaw or overrun found by the analysis (analysis/measure/faults.py)",
    "type": "object",
    "properties": {
        "kind": {"type": "string", "enum": list(KINDS)},
        "process": _OPT_STR, "dpu": _OPT_INT, "buffer": _OPT_STR, "writer": _OPT_STR, "cycle": _OPT_INT,
        "chain": {"type": "array", "items": {"type": "string"}}, "detail": {"type": "string"},
        "count": _OPT_INT, "static_load_pct": {"type": ["number", "null"]}, "root_dpu": _OPT_INT,
        "host": _OPT_STR, "dpus": {"type": "array", "items": {"type": "integer"}},
        "at_s": {"type": ["number", "null"], "description": "s from the run's first release"},
        "duration_ms": {"type": ["number", "null"]}, "behind_ms": {"type": ["number", "null"]},
        "fatal": {"type": "boolean", "description": "the design's flaw (exit 3), not the platform's"},
    },
    "required": ["kind", "detail"],
}  # fmt: skip


# One encoder for every JSON message: json.dumps makes one per call (0.7 s of 2·10^5 statuses,
# profiled).
_COMPACT = json.JSONEncoder(separators=(",", ":")).encode


def export(data: RunAnalysis, mcap: str | os.PathLike[str]) -> dict[str, int]:
    """Write the MCAP; returns counts of what was written."""
    with replaced(mcap) as part, DropBehindFile(part) as stream:
        out = BulkWriter(stream, library="skeleton skel export")
        timing = _timing_source(data, out)
        json_messages = _JsonMessages(out)
        json_messages.add_control(data)
        json_messages.add_faults(data)
        out.messages([timing, json_messages.source()])
        _attach(out, data)
        out.finish()
    return {"messages": out.messages_written, "timing": len(timing.size), "topics": len(out.channels)}


class _JsonMessages:
    """The few messages written as JSON, gathered before the one call that writes all."""

    def __init__(self, out: BulkWriter) -> None:
        self.out = out
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        self.rows: list[tuple[int, int, int, int]] = []  # (channel, sequence, log_time, publish_time)
        self.payloads: list[bytes] = []

    def add(self, topic: str, schema: dict[str, Any], meta: dict[str, str], sequence: int, log_time: int,
            publish_time: int, body: dict[str, Any]) -> None:  # fmt: skip
        if topic not in self.channels:
            title = schema["title"]
            if title not in self.schemas:
                self.schemas[title] = self.out.schema(title, "jsonschema", json.dumps(schema).encode())
            self.channels[topic] = self.out.channel(topic, "json", self.schemas[title], meta)
        self.rows.append((self.channels[topic], sequence, log_time, publish_time))
        self.payloads.append(_COMPACT(body).encode())

    def add_control(self, data: RunAnalysis) -> None:
        """The control-plane messages that decode (the attached log keeps the rest)."""
        log = data.log
        for channel, (cls, pattern) in MESSAGE_CHANNELS.items():
            schema = schema_of(cls)
            meta = {"lcm_channel": channel, "lcm_type": type_name(cls)}
            idx = log.indices(channel)
            rows = to_json_many(cls, log.buf, log.data_offset[idx], log.data_len[idx], log.release)
            decoded = ((t, row) for t, row in zip(log.utime_us[idx].tolist(), rows, strict=True)
                       if row is not None)  # fmt: skip
            for seq, (utime, row) in enumerate(decoded):
                topic = pattern.format(dpu=row.get("dpu", 0))
                publish = row["utc_ns"] if cls is skelmsg.status_t else utime * 1000
                self.add(topic, schema, meta, seq, utime * 1000, max(publish, 0), row)

    def add_faults(self, data: RunAnalysis) -> None:
        for when, fault in _faults(data):
            self.add(FAULTS_TOPIC, FAULT_SCHEMA, {}, 0, max(when, 0), max(when, 0), asdict(fault))

    def source(self) -> MessageSource:
        channel, sequence, log_time, publish = (list(c) for c in zip(*self.rows, strict=True)) if self.rows \
            else ([], [], [], [])  # fmt: skip
        return MessageSource.of_bytes(channel, sequence, log_time, publish, self.payloads)


def _timing_source(data: RunAnalysis, out: BulkWriter) -> MessageSource:
    """Every process cycle of the run as a CDR message, built chunk by chunk from the
    record columns (no Python per record)."""
    run = data.recorded
    recs = run.records
    n = len(recs)
    cols = {k: recs[k] for k in ("dpu", "process", "generation", "batch_seq", *CYCLE_FIELDS, "flags")}
    # Position of each record inside its batch: batches are contiguous in `records`.
    new_batch = np.r_[True, (np.diff(cols["dpu"]) != 0) | (np.diff(cols["batch_seq"]) != 0)]
    batch_start = np.flatnonzero(new_batch) if n else np.zeros(0, dtype=np.int64)
    per_batch = np.diff(np.r_[batch_start, n])
    index = np.arange(n) - np.repeat(batch_start, per_batch)
    logged = np.repeat(_logged_us(data, cols["dpu"][batch_start], cols["batch_seq"][batch_start]), per_batch)
    log_time = data.to_utc_ns(cols["dpu"], cols["start_ns"])
    release = data.to_utc_ns(cols["dpu"], cols["release_ns"])
    response_us = (cycle_end_ns(recs) - cols["release_ns"]) / 1000.0
    in_cols = {k: run.inputs[k] for k in INPUT_INTS}
    starts = input_starts(run.inputs, n)
    in_first, in_count = starts[:-1], np.diff(starts)
    channel = _timing_channels(data, out, cols["dpu"], cols["process"])

    def fill(chunk: np.ndarray, ids: np.ndarray, at: np.ndarray) -> None:
        head = np.zeros(len(ids), dtype=TIMING_CDR)
        head["encapsulation"] = CDR_LE
        head["run_id"] = run.run_id
        for k, v in cols.items():
            head[k] = v[ids]
        head["index"], head["logged_us"] = index[ids], logged[ids]
        head["release_latency_us"] = (cols["start_ns"][ids] - cols["release_ns"][ids]) / 1000.0
        head["response_us"] = response_us[ids]
        flags = cols["flags"][ids]
        for k, bit in zip(RECORD_BOOLS, (FLAG_OVERRUN, FLAG_SKIPPED, FLAG_LOCKOUT), strict=True):
            head[k] = (flags & bit) != 0
        counts = in_count[ids]
        head["ninputs"] = counts
        scatter(chunk, at, head)
        rows = concat_ranges(in_first[ids], counts)
        if not len(rows):
            return
        items = np.empty(len(rows), dtype=INPUT_CDR)
        for k, v in in_cols.items():
            items[k] = v[rows]
        items["transport_us"] = (in_cols["recv_ns"][rows] - in_cols["sent_ns"][rows]) / 1000.0
        before = np.cumsum(counts) - counts  # inputs of the earlier messages
        first = np.repeat(at + TIMING_CDR.itemsize - before * INPUT_CDR.itemsize, counts)
        scatter(chunk, first + np.arange(len(rows)) * INPUT_CDR.itemsize, items)

    return MessageSource(channel=channel, sequence=cols["cycle"], log_time=log_time, publish_time=release,
                         size=TIMING_CDR.itemsize + in_count * INPUT_CDR.itemsize, fill=fill)  # fmt: skip


def _timing_channels(data: RunAnalysis, out: BulkWriter, dpu: np.ndarray, process: np.ndarray) -> np.ndarray:
    """The MCAP channel of each record: one per (DPU, process), named as the last generation
    that has the process names it (a process of an earlier window only keeps its name)."""
    systems = [g.system for g in data.window_generations()]
    names = {p.id: p.name for s in systems for p in s.processes}
    buffers = json.dumps({str(b.id): b.name for s in systems for b in s.buffers})
    schema = out.schema("skeleton/msg/TimingRecord", "ros2msg", TIMING_SCHEMA.encode())
    keys, inverse = _pairs(dpu, process)
    ids = [
        out.channel(f"{TIMING_PREFIX}{d}/{names.get(p, f'process {p}')}", "cdr", schema,
                    {"lcm_channel": TIMING_CHANNEL, "lcm_type": "skelmsg.timing_t (one record)",
                     "dpu": str(d), "process": str(p), "buffers": buffers})
        for d, p in zip((keys // 65536 - 32768).tolist(), (keys % 65536 - 32768).tolist(), strict=True)
    ]  # fmt: skip
    return np.asarray(ids, dtype=np.uint16)[inverse] if len(ids) else np.zeros(0, np.uint16)


def _pairs(dpu: np.ndarray, process: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The distinct (dpu, process) pairs as sorted keys (dpu + 32768) * 65536 + process + 32768
    (both int16, so the key splits back), and each record's index among them. A process that
    ran on one DPU only (every run without a live move) is looked up in a table of the 2^16
    process ids instead of sorting every record's key."""
    proc = process.astype(np.int64) + 32768
    home = np.zeros(1 << 16, dtype=np.int64)
    home[proc] = dpu.astype(np.int64) + 32768
    if not np.array_equal(home[proc], dpu.astype(np.int64) + 32768):  # moved: sort the keys
        keys, inverse = np.unique((dpu.astype(np.int64) + 32768) * 65536 + proc,
                                  return_inverse=True)  # fmt: skip
        return keys, inverse.reshape(-1)
    present = np.flatnonzero(np.bincount(proc, minlength=1 << 16))
    keys = np.sort(home[present] * 65536 + present)
    index = np.zeros(1 << 16, dtype=np.int64)
    index[keys % 65536] = np.arange(len(keys))
    return keys, index[proc]


def _logged_us(data: RunAnalysis, dpu: np.ndarray, batch_seq: np.ndarray) -> np.ndarray:
    """When the logger heard each batch (dpu, batch_seq) of the run: its first copy's time."""
    log = data.log
    ok, heads = data.heads
    idx = log.indices(TIMING_CHANNEL)
    mine = np.flatnonzero(ok & (heads["run_id"] == data.recorded.run_id))[::-1]  # the first copy wins
    heard = dict(zip(zip(heads["dpu"][mine].tolist(), heads["batch_seq"][mine].tolist(), strict=True),
                     log.utime_us[idx[mine]].tolist(), strict=True))  # fmt: skip
    return np.array([heard.get(key, 0) for key in zip(dpu.tolist(), batch_seq.tolist(), strict=True)],
                    dtype=np.int64)  # fmt: skip


def _faults(data: RunAnalysis) -> Iterator[tuple[int, Any]]:
    """Each fault with its time: the start of the cycle it names (else the run's end),
    looked up among the records sorted once by (process, cycle): no pass over them per fault.
    The report's faults are its generation's: looked up in that window's records."""
    recs = data.records
    starts = data.to_utc_ns(recs["dpu"], recs["start_ns"])
    end = int(starts.max()) if len(recs) else 0
    order = np.lexsort((recs["cycle"], recs["process"]))
    process, cycle = recs["process"][order], recs["cycle"][order]
    for fault in data.report.faults:
        when = end
        found = data.system.find_process(fault.process) if fault.process else None
        if found is not None and fault.cycle is not None:
            pid = found.id
            low = np.searchsorted(process, pid, side="left")
            high = np.searchsorted(process, pid, side="right")
            at = low + np.searchsorted(cycle[low:high], fault.cycle)
            if at < high and cycle[at] == fault.cycle:
                when = int(starts[order[at]])
        yield when, fault


def _attach(out: BulkWriter, data: RunAnalysis) -> None:
    system, log = data.system, data.log
    integ = log.integrity
    sent_utc_ns = data.config.sent_utc_ns  # the wire's alone: when the host sent the config
    when = int(sent_utc_ns) if sent_utc_ns > 0 else 0
    out.attach("system.yaml", "application/yaml", system.source_text.encode(), when)
    out.attach(SOURCE_LOG, "application/x-lcm-log", memoryview(log.buf[: log.size]), when, log.release)
    out.metadata(
        METADATA,
        {
            "system": system.name,
            "run_id": str(data.report.run_id),
            "generation": str(data.report.generation),
            "source_log": os.path.basename(log.path),
            "lcm_events": str(integ.events),
            "corrupt_ranges": json.dumps([list(r) for r in integ.corrupt_ranges]),
            "truncated_tail": json.dumps(integ.truncated_tail),
            # The topics hold the messages without their seals (the attached log keeps them).
            "signed": json.dumps(integ.signed),
            "checked": json.dumps(integ.checked),
            "unauthenticated": str(integ.unauthenticated),
            "clock": "timing log_time = DPU monotonic + median(status_t utc_ns - mono_ns) of that DPU",
        },
    )
