"""`skel export RUN.lcm RUN.mcap`: one run as an MCAP file Foxglove can open.

MCAP has no LCM encoding and Foxglove cannot decode LCM, so every message is JSON
with a JSON Schema (lcmjson.py derives both from the generated types). Topics:

  /timing/<dpu>/<process>   one message per process cycle (timing_t record + its inputs)
  /dpu/<id>/status          status_t          /dpu/<id>/report   report_t
  /dpu/<id>/clock_offset    clock_offset_t    /config            config_t (every generation)
  /command                  command_t         /faults            the report's faults
  /lcm/raw                  LCM events kept as bytes: undecodable ones and duplicate batches

Times: a timing message's log_time is the cycle's start mapped to wall clock (see
measure/run.py: per-DPU utc - mono offset from status_t), publish_time its release;
every other message's log_time is the lcm-logger receive time. `sequence` is the
index of the LCM event the message came from, so mcapsource.py can rebuild the
log (same events, same order, same bytes) and `skel report RUN.mcap` gives the
same tables. The system file is attached as system.yaml; metadata "skeleton" holds
the system name, run id, generation and the source log's integrity.
"""

from __future__ import annotations

import base64
import json
import os
from collections.abc import Iterator
from dataclasses import asdict
from pathlib import Path
from typing import Any

import numpy as np
from mcap.writer import Writer

import skelmsg
from skelmsg import contract
from skelmsg.contract import TIMING_CHANNEL

from ..measure.faults import KINDS
from ..measure.metrics import cycle_end_ns
from ..measure.run import RunAnalysis
from ..read.lcmjson import schema_of, to_json, type_name
from ..read.mcapformat import FAULTS_TOPIC, INPUT_FIELDS, METADATA, RAW_TOPIC, TIMING_PREFIX
from ..read.records import (
    CYCLE_FIELDS,
    FLAG_LOCKOUT,
    FLAG_OVERRUN,
    FLAG_SKIPPED,
    decode_timing,
)

# LCM channel -> (type, topic prefix); the DPU id completes per-DPU topics.
MESSAGE_CHANNELS: dict[str, tuple[type, str]] = {
    contract.CONFIG_CHANNEL: (skelmsg.config_t, "/config"),
    contract.COMMAND_CHANNEL: (skelmsg.command_t, "/command"),
    contract.STATUS_CHANNEL: (skelmsg.status_t, "/dpu/{dpu}/status"),
    contract.REPORT_CHANNEL: (skelmsg.report_t, "/dpu/{dpu}/report"),
    contract.CLOCK_CHANNEL: (skelmsg.clock_offset_t, "/dpu/{dpu}/clock_offset"),
}
_INT = {"type": "integer"}
_NS = {"type": "integer", "description": "DPU CLOCK_MONOTONIC, ns"}
_CYCLE = [*CYCLE_FIELDS, "flags"]
TIMING_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "skeleton.timing_record",
    "description": "One process cycle (a timing_t record) with its input records. "
    "Ids: `index` is the record's position in its timing_t batch.",
    "type": "object",
    "properties": {
        **{k: _INT for k in ("run_id", "dpu", "process", "generation", "batch_seq", "index", "logged_us")},
        "process_name": {"type": "string"},
        **{k: (_NS if k in ("release_ns", "sched_ns", "start_ns") else _INT) for k in _CYCLE},
        **{k: {"type": "boolean"} for k in ("overrun", "skipped", "lockout")},
        "release_latency_us": {"type": "number", "description": "start - release"},
        "response_us": {"type": "number", "description": "end of the cycle's work - release"},
        "inputs": {
            "type": "array",
            "items": {
                "type": "object",
                "properties": {**{k: _INT for k in INPUT_FIELDS}, "buffer_name": {"type": "string"},
                               "transport_us": {"type": "number", "description": "recv_ns - sent_ns"}},
                "required": [*INPUT_FIELDS, "buffer_name"],
            },
        },
    },
    "required": ["run_id", "dpu", "process", "generation", "batch_seq", "index", "logged_us", *_CYCLE,
                 "inputs"],
}  # fmt: skip
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
RAW_SCHEMA: dict[str, Any] = {
    "$schema": "https://json-schema.org/draft/2020-12/schema",
    "title": "skeleton.lcm_event",
    "description": "An LCM event kept as bytes (it did not decode, or repeats a timing batch)",
    "type": "object",
    "properties": {"channel": {"type": "string"}, "utime_us": _INT,
                   "data": {"type": "string", "contentEncoding": "base64"}},
    "required": ["channel", "utime_us", "data"],
}  # fmt: skip


class _Out:
    """The MCAP writer with schemas and channels registered on first use."""

    def __init__(self, writer: Writer) -> None:
        self.writer = writer
        self.schemas: dict[str, int] = {}
        self.channels: dict[str, int] = {}

    def channel(self, topic: str, schema: dict[str, Any], meta: dict[str, str]) -> int:
        if topic not in self.channels:
            title = schema["title"]
            if title not in self.schemas:
                self.schemas[title] = self.writer.register_schema(
                    name=title, encoding="jsonschema", data=json.dumps(schema).encode()
                )
            self.channels[topic] = self.writer.register_channel(
                topic=topic, message_encoding="json", schema_id=self.schemas[title], metadata=meta
            )
        return self.channels[topic]


def export(data: RunAnalysis, mcap: str | os.PathLike[str]) -> dict[str, int]:
    """Write the MCAP; returns counts of what was written."""
    messages = sorted(_messages(data), key=lambda m: (m[0], m[1]))
    tmp = Path(f"{os.fspath(mcap)}.part")
    with open(tmp, "wb") as stream:
        out = _Out(Writer(stream))
        out.writer.start(profile="", library="skeleton skel export")
        for log_time, seq, topic, schema, meta, publish_time, body in messages:
            out.writer.add_message(
                channel_id=out.channel(topic, schema, meta), log_time=log_time,
                data=json.dumps(body, separators=(",", ":")).encode(),
                publish_time=publish_time, sequence=seq,
            )  # fmt: skip
        _attach(out.writer, data)
        out.writer.finish()
    tmp.replace(mcap)  # never leave a half-written file under the final name
    timing = sum(1 for m in messages if m[2].startswith(TIMING_PREFIX))
    return {"messages": len(messages), "timing": timing, "topics": len(out.channels)}


Message = tuple[int, int, str, dict[str, Any], dict[str, str], int, dict[str, Any]]


def _messages(data: RunAnalysis) -> Iterator[Message]:
    log = data.log
    raw = set(_raw_timing_events(data))
    for channel, (cls, pattern) in MESSAGE_CHANNELS.items():
        schema = schema_of(cls)
        meta = {"lcm_channel": channel, "lcm_type": type_name(cls)}
        for i in log.indices(channel).tolist():
            utime = int(log.utime_us[i])
            try:
                msg = cls.decode(bytes(log.data(i)))  # type: ignore[attr-defined]
            except Exception:  # malformed: kept as bytes so the rebuilt log counts it too
                raw.add(i)
                continue
            topic = pattern.format(dpu=getattr(msg, "dpu", 0))
            publish = msg.utc_ns if cls is skelmsg.status_t else utime * 1000
            yield utime * 1000, i, topic, schema, meta, max(publish, 0), to_json(msg)
    for i in sorted(raw):
        channel = log.channels[int(log.channel_id[i])]
        body = {"channel": channel, "utime_us": int(log.utime_us[i]),
                "data": base64.b64encode(bytes(log.data(i))).decode("ascii")}  # fmt: skip
        utime = int(log.utime_us[i]) * 1000
        yield utime, i, RAW_TOPIC, RAW_SCHEMA, {"lcm_channel": channel}, utime, body
    yield from _timing_messages(data)
    yield from _fault_messages(data)


def _batch_events(data: RunAnalysis) -> dict[tuple[int, int], int]:
    """(dpu, batch_seq) of every kept batch -> index of its LCM event (the first good copy)."""
    log, run = data.log, data.recorded
    idx = log.indices(TIMING_CHANNEL)
    ok, heads = data.heads
    kept = set(zip(run.records["dpu"].tolist(), run.records["batch_seq"].tolist(), strict=True))
    out: dict[tuple[int, int], int] = {}
    mine = np.flatnonzero(ok & (heads["run_id"] == run.run_id))
    for j in mine.tolist():
        key = (int(heads["dpu"][j]), int(heads["batch_seq"][j]))
        if key in kept and key not in out and _decodes(data, int(idx[j])):
            out[key] = int(idx[j])
    return out


def _decodes(data: RunAnalysis, i: int) -> bool:
    log = data.log
    one = decode_timing(log.buf, log.data_offset[i : i + 1], log.data_len[i : i + 1], data.recorded.run_id)
    return one.batches == 1 and one.malformed == 0


def _raw_timing_events(data: RunAnalysis) -> list[int]:
    """Timing events the records do not represent: undecodable (any run) and repeated
    batches of this run. Other runs' good batches are not exported."""
    log = data.log
    idx = log.indices(TIMING_CHANNEL)
    ok, heads = data.heads
    used = set(_batch_events(data).values())
    mine = ok & (heads["run_id"] == data.recorded.run_id)
    return [int(i) for i, m, good in zip(idx.tolist(), mine.tolist(), ok.tolist(), strict=True)
            if not good or (m and i not in used)]  # fmt: skip


def _timing_messages(data: RunAnalysis) -> Iterator[Message]:
    run, log = data.recorded, data.log
    recs = run.records
    if not len(recs):
        return
    events = _batch_events(data)
    names = data.process_names()
    buffers = {b.id: b.name for b in data.config.buffers}
    # Position of each record inside its batch: batches are contiguous in `records`.
    key_change = np.r_[True, (np.diff(recs["dpu"]) != 0) | (np.diff(recs["batch_seq"]) != 0)]
    first = np.maximum.accumulate(np.where(key_change, np.arange(len(recs)), 0))
    index = (np.arange(len(recs)) - first).tolist()
    order = np.argsort(run.inputs["record"], kind="stable")
    ins = run.inputs[order]
    in_bounds = np.searchsorted(ins["record"], np.arange(len(recs) + 1)).tolist()
    in_cols = {k: ins[k].tolist() for k in INPUT_FIELDS}
    cols = {k: recs[k].tolist() for k in ("dpu", "process", "generation", "batch_seq", *_CYCLE)}
    log_times = data.to_utc_ns(recs["dpu"], recs["start_ns"]).tolist()
    releases = data.to_utc_ns(recs["dpu"], recs["release_ns"]).tolist()
    response_us = ((cycle_end_ns(recs) - recs["release_ns"]) / 1000.0).tolist()
    for r in range(len(recs)):
        dpu, proc, flags = cols["dpu"][r], cols["process"][r], cols["flags"][r]
        event = events[(dpu, cols["batch_seq"][r])]
        a, b = in_bounds[r], in_bounds[r + 1]
        inputs = []
        for k in range(a, b):
            item = {f: in_cols[f][k] for f in INPUT_FIELDS}
            item["buffer_name"] = buffers.get(item["buffer"], f"buffer {item['buffer']}")
            item["transport_us"] = (item["recv_ns"] - item["sent_ns"]) / 1000.0
            inputs.append(item)
        body: dict[str, Any] = {
            "run_id": run.run_id, "dpu": dpu, "process": proc,
            "process_name": names.get(proc, f"process {proc}"),
            "generation": cols["generation"][r], "batch_seq": cols["batch_seq"][r], "index": index[r],
            "logged_us": int(log.utime_us[event]),
            **{k: cols[k][r] for k in _CYCLE},
            "overrun": bool(flags & FLAG_OVERRUN), "skipped": bool(flags & FLAG_SKIPPED),
            "lockout": bool(flags & FLAG_LOCKOUT),
            "release_latency_us": (cols["start_ns"][r] - cols["release_ns"][r]) / 1000.0,
            "response_us": response_us[r],
            "inputs": inputs,
        }  # fmt: skip
        topic = f"{TIMING_PREFIX}{dpu}/{body['process_name']}"
        meta = {"lcm_channel": TIMING_CHANNEL, "lcm_type": "skelmsg.timing_t (one record)"}
        yield max(log_times[r], 0), event, topic, TIMING_SCHEMA, meta, max(releases[r], 0), body


def _fault_messages(data: RunAnalysis) -> Iterator[Message]:
    """One message per fault, at the start of the cycle it names (else at the run's end)."""
    recs = data.records
    ids = {p.name: p.id for p in data.config.processes}
    end = int(data.to_utc_ns(recs["dpu"], recs["start_ns"]).max()) if len(recs) else 0
    for fault in data.report.faults:
        when = end
        if fault.process in ids and fault.cycle is not None:
            hit = recs[(recs["process"] == ids[fault.process]) & (recs["cycle"] == fault.cycle)]
            if len(hit):
                when = int(data.to_utc_ns(hit["dpu"][:1], hit["start_ns"][:1])[0])
        yield max(when, 0), 0, FAULTS_TOPIC, FAULT_SCHEMA, {}, max(when, 0), asdict(fault)


def _attach(writer: Writer, data: RunAnalysis) -> None:
    config, integ = data.config, data.log.integrity
    when = int(config.sent_utc_ns) if config.sent_utc_ns > 0 else 0
    writer.add_attachment(create_time=when, log_time=when, name="system.yaml",
                          media_type="application/yaml", data=config.source.encode())  # fmt: skip
    writer.add_metadata(
        METADATA,
        {
            "system": config.system,
            "run_id": str(data.report.run_id),
            "generation": str(config.generation),
            "source_log": os.path.basename(data.log.path),
            "lcm_events": str(integ.events),
            "corrupt_ranges": json.dumps([list(r) for r in integ.corrupt_ranges]),
            "truncated_tail": json.dumps(integ.truncated_tail),
            # The MCAP holds the messages without their seals: whether a key checked them goes here.
            "signed": json.dumps(integ.signed),
            "checked": json.dumps(integ.checked),
            "unauthenticated": str(integ.unauthenticated),
            "clock": "timing log_time = DPU monotonic + median(status_t utc_ns - mono_ns) of that DPU",
        },
    )
