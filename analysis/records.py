"""timing_t batches -> one structured array of process-cycle records and one of input
records, for one run; lost batches from batch_seq gaps.

Works on raw message bytes, so a log, a replay and a live subscription all use it.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

import skelmsg

from .flatdecode import FlatLayout, decode_heads, decode_many
from .logreader import Log

TIMING_CHANNEL = "SKEL_TIMING"
TIMING = FlatLayout.of(skelmsg.timing_t)
FLAG_OVERRUN = skelmsg.timing_t.FLAG_OVERRUN
FLAG_SKIPPED = skelmsg.timing_t.FLAG_SKIPPED
FLAG_LOCKOUT = skelmsg.timing_t.FLAG_LOCKOUT

# The scalars in front of the first array: enough to pick a run without decoding arrays.
if TIMING.head[0][:4] != ("dpu", "run_id", "generation", "batch_seq"):
    raise ImportError(f"timing_t changed: its header is now {TIMING.head[0]}; update analysis/records.py")

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


def _timing_events(log: Log) -> tuple[np.ndarray, np.ndarray]:
    idx = log.indices(TIMING_CHANNEL)
    return log.data_offset[idx], log.data_len[idx]


def run_ids(log: Log) -> list[int]:
    """Run ids with timing records, ordered by their last batch in the log."""
    ok, heads = decode_heads(TIMING, log.buf, *_timing_events(log))
    order: dict[int, None] = {}
    for run in heads["run_id"][ok].tolist():
        order.pop(run, None)
        order[run] = None
    return list(order)


def load_run(
    log: Log, run_id: int | None = None, expected_batches: dict[int, int] | None = None
) -> RunRecords:
    """The records of one run (default: the last run with timing records), straight
    from the log's memory map."""
    if run_id is None:
        runs = run_ids(log)
        run_id = runs[-1] if runs else 0
    return decode_timing(log.buf, *_timing_events(log), run_id=run_id, expected_batches=expected_batches)


def decode_run(
    messages: Iterable[memoryview | bytes],
    run_id: int,
    malformed: int = 0,
    expected_batches: dict[int, int] | None = None,
) -> RunRecords:
    """Decode timing_t messages (raw bytes, e.g. from a live subscription) of one run."""
    datas = [bytes(m) for m in messages]
    lengths = np.array([len(d) for d in datas], dtype=np.int64)
    starts = np.cumsum(lengths) - lengths
    buf = np.frombuffer(b"".join(datas), dtype=np.uint8)
    run = decode_timing(buf, starts, lengths, run_id, expected_batches)
    run.malformed += malformed
    return run


def decode_timing(
    buf: np.ndarray,
    starts: np.ndarray,
    lengths: np.ndarray,
    run_id: int,
    expected_batches: dict[int, int] | None = None,
) -> RunRecords:
    """The timing_t messages at buf[starts[i]:+lengths[i]] that belong to `run_id`.
    `expected_batches` (dpu -> batches the DPU says it published, from report_t)
    reveals batches lost at the end of a run."""
    ok, heads = decode_heads(TIMING, buf, starts, lengths)
    malformed = int(np.count_nonzero(~ok))
    chosen = np.flatnonzero(ok & (heads["run_id"] == run_id))
    dec = decode_many(TIMING, buf, np.asarray(starts)[chosen], np.asarray(lengths)[chosen])
    malformed += int(np.count_nonzero(~dec.ok))
    good = np.flatnonzero(dec.ok)
    table = np.stack(
        [dec.scalars[k][good] for k in ("dpu", "generation", "batch_seq")]
        + [dec.counts["n"], dec.counts["ninputs"]],
        axis=1,
    ).astype(np.int64).reshape(-1, 5)
    cols = dec.columns
    # An input record must point at a cycle record of its own batch.
    bad = _bad_inputs(cols, table)
    malformed += len(bad)
    # A re-sent or twice-logged batch must not count twice: keep the first good copy.
    keep = np.setdiff1d(np.arange(len(table)), bad)
    _, first = np.unique(table[keep][:, [0, 2]], axis=0, return_index=True)
    keep = keep[np.sort(first)]
    duplicates = len(table) - len(bad) - len(keep)
    if len(keep) < len(table):
        cols, table = _select(cols, table, keep)
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


def _select(
    cols: dict[str, np.ndarray], table: np.ndarray, keep: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Only the batches `keep` (indices into table), with their records and inputs."""
    wanted = np.zeros(len(table), dtype=bool)
    wanted[keep] = True
    rec_keep = np.repeat(wanted, table[:, 3])
    in_keep = np.repeat(wanted, table[:, 4])
    return {k: v[in_keep] if k.startswith("in_") else v[rec_keep] for k, v in cols.items()}, table[wanted]


def _bad_inputs(cols: dict[str, np.ndarray], table: np.ndarray) -> np.ndarray:
    """Batches with an in_record outside their own records."""
    if not len(table):
        return np.zeros(0, dtype=np.int64)
    batch = np.repeat(np.arange(len(table)), table[:, 4])
    rec = cols["in_record"]
    return np.unique(batch[(rec < 0) | (rec >= table[batch, 3])])


def _records(cols: dict[str, np.ndarray], table: np.ndarray) -> np.ndarray:
    total = int(table[:, 3].sum()) if len(table) else 0
    records = np.empty(total, dtype=RECORD_DTYPE)
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
    inputs = np.empty(total, dtype=INPUT_DTYPE)
    if total == 0:
        return inputs
    # in_record is relative to its batch: add the batch's first record index.
    first_record = np.concatenate([[0], np.cumsum(table[:, 3])[:-1]])
    index = np.repeat(first_record, table[:, 4]) + cols["in_record"]
    inputs["record"] = index
    # From the contiguous columns, not the structured records (strided, slower to index).
    inputs["dpu"] = np.repeat(table[:, 0], table[:, 4])
    inputs["process"] = cols["process"][index]
    inputs["cycle"] = cols["cycle"][index]
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
