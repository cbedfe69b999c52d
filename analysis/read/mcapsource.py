"""An MCAP written by `skel export`, served back as an LCM log (logreader.Log).

Every exported message carries, as its MCAP `sequence`, the index of the LCM event
it came from: decoded messages are re-encoded with the generated types (lcmjson is
lossless), the timing records of one batch (same sequence) become one timing_t
again, and /lcm/raw holds the events that never decoded, byte for byte. The
rebuilt log therefore holds the same events in the same order, and the same
analysis (report.analyze_log) gives the same report. Integrity (event count,
corrupt ranges, truncated tail) is the source log's, from the file's metadata.
"""

from __future__ import annotations

import base64
import dataclasses
import json
import os
import struct
from collections import defaultdict
from typing import Any

from mcap.exceptions import McapError
from mcap.reader import make_reader

import skelmsg
from skelmsg.contract import TIMING_CHANNEL

from .lcmjson import from_json, lcm_class
from .logreader import Integrity, Log, encode_events, read_bytes
from .mcapformat import FAULTS_TOPIC, INPUT_FIELDS, METADATA, RAW_TOPIC, RECORD_FIELDS, TIMING_PREFIX


class McapSourceError(OSError):
    """The file is not an MCAP written by `skel export` (an OSError, so callers that
    report unreadable files need no new case)."""


def read_as_log(path: str | os.PathLike[str]) -> Log:
    """The LCM log an export came from (see the module comment). Raises OSError."""
    events: list[tuple[int, int, str, bytes]] = []  # (sequence, utime_us, channel, data)
    batches: dict[int, list[dict[str, Any]]] = defaultdict(list)
    try:
        with open(path, "rb") as stream:
            reader = make_reader(stream)
            meta = {m.name: m.metadata for m in reader.iter_metadata()}
            if METADATA not in meta:
                raise McapSourceError(f"{os.fspath(path)}: not an MCAP written by `skel export`")
            for _, channel, message in reader.iter_messages(log_time_order=False):
                _collect(channel, message, events, batches)
    except McapError as e:
        raise McapSourceError(f"{os.fspath(path)}: not a readable MCAP file ({e})") from e
    except (ValueError, KeyError, struct.error) as e:
        raise McapSourceError(f"{os.fspath(path)}: unexpected content ({e})") from e
    for seq, records in batches.items():
        utime, data = _timing_batch(records)
        events.append((seq, utime, TIMING_CHANNEL, data))
    events.sort(key=lambda e: e[0])
    info = meta[METADATA]
    integrity = Integrity(
        events=int(info["lcm_events"]),
        corrupt_ranges=[(int(a), int(b)) for a, b in json.loads(info["corrupt_ranges"])],
        truncated_tail=bool(json.loads(info["truncated_tail"])),
        signed=bool(json.loads(info.get("signed", "false"))),
        checked=bool(json.loads(info.get("checked", "false"))),
        unauthenticated=int(info.get("unauthenticated", "0")),
    )
    return _log(os.fspath(path), events, integrity)


def _collect(channel: Any, message: Any, events: list[tuple[int, int, str, bytes]],
             batches: dict[int, list[dict[str, Any]]]) -> None:  # fmt: skip
    topic = channel.topic
    if topic == FAULTS_TOPIC:
        return  # derived by the analysis, not an LCM event
    body = json.loads(message.data)
    if topic == RAW_TOPIC:
        events.append((message.sequence, body["utime_us"], body["channel"], base64.b64decode(body["data"])))
    elif topic.startswith(TIMING_PREFIX):
        batches[message.sequence].append(body)
    else:
        cls = lcm_class(channel.metadata["lcm_type"])
        data = from_json(cls, body).encode()
        events.append((message.sequence, message.log_time // 1000, channel.metadata["lcm_channel"], data))


def _timing_batch(records: list[dict[str, Any]]) -> tuple[int, bytes]:
    """One timing_t from its records (ordered by their position in the batch)."""
    records.sort(key=lambda r: r["index"])
    head = records[0]
    t = skelmsg.timing_t()
    for name in ("dpu", "run_id", "generation", "batch_seq"):
        setattr(t, name, head[name])
    t.n = len(records)
    for name in RECORD_FIELDS:
        setattr(t, name, [r[name] for r in records])
    inputs = [(r["index"], i) for r in records for i in r["inputs"]]
    t.ninputs = len(inputs)
    t.in_record = [index for index, _ in inputs]
    for name in INPUT_FIELDS:
        setattr(t, f"in_{name}", [i[name] for _, i in inputs])
    return head["logged_us"], t.encode()


def _log(path: str, events: list[tuple[int, int, str, bytes]], integrity: Integrity) -> Log:
    """A Log over an in-memory LCM log file holding `events`, with the source's integrity."""
    log = read_bytes(encode_events((utime, channel, data) for _, utime, channel, data in events), path)
    return dataclasses.replace(log, integrity=integrity)
