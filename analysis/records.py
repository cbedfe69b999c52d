"""timing_t batches -> one structured array of process-cycle records and one of input
records, for one run; lost batches from batch_seq gaps.

Works on raw message bytes, so a log, a replay and a live subscription all use it.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field

import numpy as np
import skelmsg

from .flatdecode import FlatLayout, MalformedMessage, concat_columns, decode_flat
from .logreader import Log

TIMING_CHANNEL = "SKEL_TIMING"
TIMING = FlatLayout.of(skelmsg.timing_t)
FLAG_OVERRUN = skelmsg.timing_t.FLAG_OVERRUN
FLAG_SKIPPED = skelmsg.timing_t.FLAG_SKIPPED
FLAG_LOCKOUT = skelmsg.timing_t.FLAG_LOCKOUT

# The scalars in front of the first array: enough to pick a run without decoding arrays.
_HEAD_NAMES, _HEAD = TIMING.head
if _HEAD_NAMES[:4] != ("dpu", "run_id", "generation", "batch_seq"):
    raise ImportError(f"timing_t changed: its header is now {_HEAD_NAMES}; update analysis/records.py")

_CYCLE_FIELDS = (
    "cycle", "minor", "release_ns", "start_ns", "comm_in_ns", "blocked_ns",
    "compute_ns", "comm_out_ns", "idle_ns", "slack_ns",
)  # fmt: skip
RECORD_DTYPE = np.dtype(
    [("dpu", "i2"), ("process", "i2"), ("generation", "i8"), ("batch_seq", "i8")]
    + [(name, "i8") for name in _CYCLE_FIELDS]
    + [("flags", "i1")]
)
INPUT_DTYPE = np.dtype(
    [
        ("record", "i8"),  # index into the records array
        ("dpu", "i2"),
        ("process", "i2"),
        ("cycle", "i8"),
        ("buffer", "i2"),
        ("seq", "i8"),
        ("new", "i1"),
        ("dropped", "i4"),
        ("received", "i4"),
        ("sent_ns", "i8"),
        ("recv_ns", "i8"),
    ]
)


@dataclass
class RunRecords:
    """Every timing record of one run."""

    run_id: int
    records: np.ndarray  # RECORD_DTYPE, in arrival order
    inputs: np.ndarray  # INPUT_DTYPE
    batches: int  # distinct batches decoded
    generations: list[int]
    lost_batches: list[dict[str, int]] = field(default_factory=list)
    malformed: int = 0  # timing messages that failed to decode (counted, skipped)
    duplicates: int = 0  # batches seen twice (same dpu, batch_seq)


def batch_heads(messages: Sequence[memoryview | bytes]) -> tuple[np.ndarray, np.ndarray]:
    """(dpu, run_id, generation, batch_seq) of each message as an (N, 4) int64 array,
    and a mask of the messages whose fingerprint and header are readable."""
    fmt = _HEAD
    heads = np.zeros((len(messages), 4), dtype=np.int64)
    ok = np.zeros(len(messages), dtype=bool)
    fp = TIMING.fingerprint
    for i, data in enumerate(messages):
        if len(data) >= 8 + fmt.size and data[:8] == fp:
            heads[i] = fmt.unpack_from(data, 8)[:4]
            ok[i] = True
    return heads, ok


def run_ids(log: Log) -> list[int]:
    """Run ids with timing records, ordered by their last batch in the log."""
    heads, ok = batch_heads([d for _, d in log.messages(TIMING_CHANNEL)])
    order: dict[int, None] = {}
    for run in heads[ok, 1].tolist():
        order.pop(run, None)
        order[run] = None
    return list(order)


def load_run(
    log: Log, run_id: int | None = None, expected_batches: dict[int, int] | None = None
) -> RunRecords:
    """The records of one run (default: the last run with timing records)."""
    messages = [d for _, d in log.messages(TIMING_CHANNEL)]
    heads, ok = batch_heads(messages)
    if run_id is None:
        runs = heads[ok, 1]
        if len(runs) == 0:
            return decode_run([], run_id=0, malformed=int((~ok).sum()))
        run_id = int(runs[-1])
    chosen = [messages[i] for i in np.flatnonzero(ok & (heads[:, 1] == run_id)).tolist()]
    return decode_run(chosen, run_id, malformed=int((~ok).sum()), expected_batches=expected_batches)


def decode_run(
    messages: Iterable[memoryview | bytes],
    run_id: int,
    malformed: int = 0,
    expected_batches: dict[int, int] | None = None,
) -> RunRecords:
    """Decode timing_t messages of one run. `expected_batches` (dpu -> batches the DPU
    says it published, from report_t) lets us see batches lost at the end of a run."""
    parts = []
    heads: list[tuple[int, int, int, int, int]] = []  # dpu, generation, batch_seq, n, ninputs
    seen: set[tuple[int, int]] = set()
    duplicates = 0
    for data in messages:
        buf = np.frombuffer(data, dtype=np.uint8)
        try:
            scalars, arrays = decode_flat(TIMING, buf, 0, len(buf))
            _check_inputs(scalars, arrays)
        except MalformedMessage:
            malformed += 1
            continue
        if scalars["run_id"] != run_id:
            continue
        key = (scalars["dpu"], scalars["batch_seq"])
        if key in seen:
            duplicates += 1  # a re-sent or twice-logged batch must not count twice
            continue
        seen.add(key)
        parts.append(arrays)
        heads.append((key[0], scalars["generation"], key[1], scalars["n"], scalars["ninputs"]))
    cols = concat_columns(parts, TIMING.arrays)
    table = np.array(heads, dtype=np.int64).reshape(-1, 5)
    records = _records(cols, table)
    inputs = _inputs(cols, table, records)
    return RunRecords(
        run_id=run_id,
        records=records,
        inputs=inputs,
        batches=len(table),
        generations=sorted(set(table[:, 1].tolist())),
        lost_batches=lost_batches(table[:, 0], table[:, 2], expected_batches),
        malformed=malformed,
        duplicates=duplicates,
    )


def _check_inputs(scalars: dict[str, int], arrays: list[tuple[tuple[str, ...], np.ndarray]]) -> None:
    """An input record must point at a cycle record of its own batch."""
    for names, view in arrays:
        if "in_record" in names:
            rec = view[names.index("in_record")]
            if len(rec) and (rec.min() < 0 or rec.max() >= scalars["n"]):
                raise MalformedMessage("timing_t: in_record out of range")


def _records(cols: dict[str, np.ndarray], table: np.ndarray) -> np.ndarray:
    total = int(table[:, 3].sum()) if len(table) else 0
    records = np.zeros(total, dtype=RECORD_DTYPE)
    if total == 0:
        return records
    counts = table[:, 3]
    records["dpu"] = np.repeat(table[:, 0], counts)
    records["generation"] = np.repeat(table[:, 1], counts)
    records["batch_seq"] = np.repeat(table[:, 2], counts)
    records["process"] = cols["process"]
    records["flags"] = cols["flags"]
    for name in _CYCLE_FIELDS:
        records[name] = cols[name]
    return records


def _inputs(cols: dict[str, np.ndarray], table: np.ndarray, records: np.ndarray) -> np.ndarray:
    total = int(table[:, 4].sum()) if len(table) else 0
    inputs = np.zeros(total, dtype=INPUT_DTYPE)
    if total == 0:
        return inputs
    # in_record is relative to its batch: add the batch's first record index.
    first_record = np.concatenate([[0], np.cumsum(table[:, 3])[:-1]])
    index = np.repeat(first_record, table[:, 4]) + cols["in_record"]
    inputs["record"] = index
    inputs["dpu"] = records["dpu"][index]
    inputs["process"] = records["process"][index]
    inputs["cycle"] = records["cycle"][index]
    inputs["buffer"] = cols["in_buffer"]
    inputs["seq"] = cols["in_seq"]
    inputs["new"] = cols["in_new"]
    inputs["dropped"] = cols["in_dropped"]
    inputs["received"] = cols["in_received"]
    inputs["sent_ns"] = cols["in_sent_ns"]
    inputs["recv_ns"] = cols["in_recv_ns"]
    return inputs


def lost_batches(
    dpu: np.ndarray, batch_seq: np.ndarray, expected: dict[int, int] | None = None
) -> list[dict[str, int]]:
    """Gaps in each DPU's batch_seq (which runs from 0): [{dpu, from_seq, to_seq}], inclusive."""
    lost: list[dict[str, int]] = []
    dpus = set(np.unique(dpu).tolist()) | set((expected or {}).keys())
    for d in sorted(dpus):
        seqs = np.unique(batch_seq[dpu == d])
        previous = -1
        for s in seqs.tolist():
            if s > previous + 1:
                lost.append({"dpu": d, "from_seq": previous + 1, "to_seq": s - 1})
            previous = s
        published = (expected or {}).get(d)
        if published is not None and published - 1 > previous:
            lost.append({"dpu": d, "from_seq": previous + 1, "to_seq": published - 1})
    return lost
