"""timing_t batches -> one table of process-cycle records and one of input records
(coltable.ColumnTable: columns, read like structured arrays of RECORD_DTYPE and
INPUT_DTYPE), for one run; lost batches from batch_seq gaps.

Works on raw message bytes, so a log, a replay and a live subscription all use it.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Collection, Iterable
from dataclasses import dataclass, field, replace
from functools import partial

import numpy as np

import skelmsg
from skelmsg.contract import TIMING_CHANNEL

from .coltable import ColumnTable
from .flatdecode import FlatLayout, decode_heads, decode_many
from .logreader import Log

TIMING = FlatLayout.of(skelmsg.timing_t)
FLAG_OVERRUN = skelmsg.timing_t.FLAG_OVERRUN
FLAG_SKIPPED = skelmsg.timing_t.FLAG_SKIPPED
FLAG_LOCKOUT = skelmsg.timing_t.FLAG_LOCKOUT
FLAG_RELEASE_SKIPPED = skelmsg.timing_t.FLAG_RELEASE_SKIPPED

# The scalars in front of the first array: enough to pick a run without decoding arrays.
if TIMING.head[0][:4] != ("dpu", "run_id", "generation", "batch_seq"):
    raise ImportError(f"timing_t changed: its header is now {TIMING.head[0]}; update {__file__}")

# The per-cycle fields of timing_t, in its order: the record tables, the MCAP export and
# its reader all follow this list.
CYCLE_FIELDS = (
    "cycle", "minor", "release_ns", "sched_ns", "start_ns", "comm_in_ns", "blocked_ns",
    "asked_ns", "compute_ns", "comm_out_ns", "idle_ns", "slack_ns", "stall_ns", "debt_ns",
    "preemptions",
    "preempted_ns", "event_ns", "event_queued", "event_dropped",
)  # fmt: skip
# Each per-cycle field in the type timing_t sends it in: a wider one was a copy of the
# column at decode (240 MB at 10^7 records for its three narrow counters).
_WIRE_TYPES = dict(zip(skelmsg.timing_t.__slots__, skelmsg.timing_t.__typenames__, strict=True))
RECORD_DTYPE = np.dtype(
    [("dpu", "i2"), ("process", "i2"), ("generation", "i8"), ("batch_seq", "i8")]
    + [(name, np.dtype(_WIRE_TYPES[name].removesuffix("_t"))) for name in CYCLE_FIELDS]
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
    """Every timing record of one run; of a live view that forgets, its newest (`first`)."""

    run_id: int
    records: ColumnTable  # fields of RECORD_DTYPE, in arrival order
    inputs: ColumnTable  # fields of INPUT_DTYPE, in their records' order
    batches: int  # distinct batches decoded
    generations: list[int]
    lost_batches: list[dict[str, int]] = field(default_factory=list)
    malformed: int = 0  # timing messages that failed to decode (counted, skipped)
    duplicates: int = 0  # batches seen twice (same dpu, batch_seq)
    impossible: int = 0  # records with times no cycle of the log can have (counted, left out)
    # A live view's store forgets its oldest records (host/live/recordstore.py): these are
    # from the `first`-th record heard on, and `origin_ns` is each DPU's first release of all
    # heard (a fault's at_s counts from it); None: the records' own.
    first: int = 0
    origin_ns: dict[int, int] | None = None


Heads = tuple[np.ndarray, np.ndarray]  # (decoded ok, the scalars in front of the arrays) per batch


def _timing_events(log: Log) -> tuple[np.ndarray, np.ndarray]:
    idx = log.indices(TIMING_CHANNEL)
    return log.data_offset[idx], log.data_len[idx]


def timing_heads(log: Log) -> Heads:
    """The header of every timing batch in the log, in file order: enough to pick a run,
    its generations and its DPUs' batches without decoding a record."""
    return decode_heads(TIMING, log.buf, *_timing_events(log), release=log.release)


def run_ids(log: Log, heads: Heads | None = None) -> list[int]:
    """Run ids with timing records, ordered by their last batch in the log."""
    ok, head = heads or timing_heads(log)
    order: dict[int, None] = {}
    for run in head["run_id"][ok].tolist():
        order.pop(run, None)
        order[run] = None
    return list(order)


def load_records(
    log: Log, run_id: int | None = None, expected_batches: dict[int, int] | None = None,
    heads: Heads | None = None, dpus: Collection[int] | None = None, usual: dict[str, float] | None = None,
) -> RunRecords:
    """The records of one run (default: the last run with timing records), straight
    from the log's memory map; with `dpus`, those of these DPUs alone (see decode_timing).
    Impossible records are left out against the `usual` sizes of the run's records (default:
    of those read: run_usual_sizes gives a run's to each of its parts)."""
    heads = heads or timing_heads(log)
    if run_id is None:
        runs = run_ids(log, heads)
        run_id = runs[-1] if runs else 0
    run = decode_timing(log.buf, *_timing_events(log), run_id=run_id, expected_batches=expected_batches,
                        heads=heads, release=log.release, dpus=dpus)
    span_ns = robust_span(log.utime_us[log.indices(TIMING_CHANNEL)]) * 1000
    return without_impossible(run, span_ns, usual_sizes(run.records) if usual is None else usual)


def run_usual_sizes(log: Log, run_id: int, heads: Heads) -> dict[str, float]:
    """usual_sizes of a run's records, read from about _SAMPLE of them in batches spread over
    the whole run: the same bounds for every part of it read alone (load_records' `dpus`) as
    for the whole."""
    ok, head = heads
    mine = np.flatnonzero(ok & (head["run_id"] == run_id))
    per_batch = max(1, int(head["n"][mine].sum()) // max(1, len(mine)))
    chosen = mine[:: max(1, len(mine) * per_batch // _SAMPLE)]
    starts, lengths = _timing_events(log)
    sample = decode_timing(log.buf, starts[chosen], lengths[chosen], run_id, release=log.release)
    return usual_sizes(sample.records)


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
    heads: Heads | None = None,
    release: Callable[[int, int], None] | None = None,
    dpus: Collection[int] | None = None,
) -> RunRecords:
    """The timing_t messages at buf[starts[i]:+lengths[i]] that belong to `run_id`.
    `expected_batches` (dpu -> batches the DPU says it published, from report_t)
    reveals batches lost at the end of a run; `heads`, when known, are those messages';
    `release`: see flatdecode.decode_many. With `dpus`, only their batches (a part of the
    run): a message whose header could not be decoded, whose DPU is unknown, is not counted as
    malformed (the caller counts it once), and only these DPUs' expected batches are looked for."""
    ok, heads = heads or decode_heads(TIMING, buf, starts, lengths, release)
    mine = ok & (heads["run_id"] == run_id)
    if dpus is None:
        malformed = int(np.count_nonzero(~ok))
    else:
        malformed = 0
        mine &= np.isin(heads["dpu"], list(dpus))
        expected_batches = {d: n for d, n in (expected_batches or {}).items() if d in dpus}
    chosen = np.flatnonzero(mine)
    dec = decode_many(TIMING, buf, np.asarray(starts)[chosen], np.asarray(lengths)[chosen], release)
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
    # A batch re-sent for the logger (host/live/repair.py) lands after later ones: put each
    # DPU's batches back in batch_seq order, so its records run in cycle order.
    reorder = _out_of_order(table[keep])
    if reorder:
        keep = keep[np.lexsort((table[keep][:, 2], table[keep][:, 0]))]
    duplicates = len(table) - len(bad) - len(keep)
    if reorder or len(keep) < len(table):
        cols, table = _select(cols, table, keep)
    records = _records(cols, table)
    inputs = _inputs(cols, table)
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


# LCM logs carry no checksum: a flipped bit in a record's times decodes. One start_ns 2^60 ns
# off made its DPU's elapsed 36 years and its shares 0 %. A record is impossible when one of
# its times lies further from its release, or one of its durations runs longer, than twice the
# larger of what the log spans and the median record's value of that quantity, and a minute
# more (the median: a log begun long after its run did, an overloaded DPU lagging minutes
# behind all through it), or when a duration is negative (a DPU measures none; inverted bits
# make one). The bounds come from robust figures: a damaged time stamp, or damaged records
# short of half, cannot widen them.
IMPOSSIBLE_MARGIN_NS = 60 * 10**9
# Their count's key among the malformed messages (report.json's integrity.malformed, both views).
IMPOSSIBLE = f"{TIMING_CHANNEL} (records with impossible times: damaged bytes)"
DURATIONS = ("comm_in_ns", "blocked_ns", "asked_ns", "compute_ns", "comm_out_ns", "idle_ns", "stall_ns",
             "debt_ns", "preempted_ns")  # fmt: skip
_ROWS_AT_ONCE = 1 << 20  # rows checked at a time: the float temporaries stay small
_SAMPLE = 1 << 16  # records the usual size of each quantity is read from


def robust_span(times: np.ndarray) -> int:
    """How far apart `times` lie, but for their 0.1 % at each end: 0 for none."""
    if not len(times):
        return 0
    low, high = np.quantile(times, [0.001, 0.999])
    return max(0, int(high) - int(low))


def _times(part: ColumnTable) -> dict[str, np.ndarray]:
    """|each checked time - its reference|, as floats (the difference of two damaged int64
    times can wrap into a plausible one; abs of int64's minimum stays < 0)."""
    release = part["release_ns"].astype(np.float64)
    start = part["start_ns"].astype(np.float64)
    event = part["event_ns"]
    return {
        "start_ns": np.abs(start - release),
        "sched_ns": np.abs(part["sched_ns"] - release),
        "slack_ns": np.abs(part["slack_ns"].astype(np.float64)),
        "event_ns": np.where(event != -1, np.abs(start - event), np.nan),  # NaN: no event cycle
    }


def _magnitudes(part: ColumnTable) -> dict[str, np.ndarray]:
    """_times, and |each duration| as a float."""
    return _times(part) | {name: np.abs(part[name].astype(np.float64)) for name in DURATIONS}


def _median(values: np.ndarray) -> float:
    """The median of the values that are numbers; 0 for none."""
    numbers = values[~np.isnan(values)]
    return float(np.median(numbers)) if len(numbers) else 0.0


def usual_sizes(records: ColumnTable) -> dict[str, float]:
    """The median record's value of each quantity impossible() checks (read from at most
    _SAMPLE of `records`; 0 for none)."""
    sample = _magnitudes(records[:: max(1, len(records) // _SAMPLE)])
    return {name: _median(values) for name, values in sample.items()}


def impossible(records: ColumnTable, span_ns: int, usual: dict[str, float] | None = None) -> np.ndarray:
    """Mask of the impossible records (see above) of a log spanning `span_ns`, against the
    `usual` sizes (usual_sizes) of other records, or by default of `records` themselves."""
    out = np.zeros(len(records), dtype=bool)
    if not len(records):
        return out
    usual = usual_sizes(records) if usual is None else usual
    bounds = {name: 2 * max(span_ns, size) + IMPOSSIBLE_MARGIN_NS for name, size in usual.items()}
    for lo in range(0, len(records), _ROWS_AT_ONCE):
        part = records[lo : lo + _ROWS_AT_ONCE]
        bad = np.zeros(len(part), dtype=bool)
        for name, values in _times(part).items():
            bad |= values > bounds[name]
        for name in DURATIONS:
            # Negative, or longer than its bound: a negative int64 read as unsigned is above any
            # bound under 2^63 ns. One comparison, where a float's abs and a sign test took more
            # passes and two temporaries: this check took 0.31-0.35 s of CPU over 10^7 records
            # against 0.65-0.78 s.
            bad |= part[name].view(np.uint64) > np.uint64(min(math.floor(bounds[name]), 2**63 - 1))
        out[lo : lo + len(part)] = bad
    return out


def without_impossible(run: RunRecords, span_ns: int, usual: dict[str, float]) -> RunRecords:
    """`run` less its impossible records (and their inputs) against the `usual` sizes, counted in
    run.impossible."""
    bad = impossible(run.records, span_ns, usual)
    if not bad.any():
        return run
    records, inputs = select(run.records, run.inputs, ~bad)
    return replace(run, records=records, inputs=inputs, impossible=int(np.count_nonzero(bad)))


def select(records: ColumnTable, inputs: ColumnTable, keep: np.ndarray) -> tuple[ColumnTable, ColumnTable]:
    """The records of mask `keep` and their input records, re-indexed to them."""
    rows = np.flatnonzero(keep)
    mine = inputs[keep[inputs["record"]]].copy() if len(inputs) else inputs
    mine["record"] = np.searchsorted(rows, mine["record"])
    return records[rows], mine


def _out_of_order(table: np.ndarray) -> bool:
    """Some DPU's batch_seq goes backwards in `table`'s (dpu, generation, batch_seq, ...) rows."""
    order = np.argsort(table[:, 0], kind="stable")
    dpu, seq = table[order, 0], table[order, 2]
    return bool(np.any((np.diff(dpu) == 0) & (np.diff(seq) < 0)))


def _select(
    cols: dict[str, np.ndarray], table: np.ndarray, keep: np.ndarray
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Only the batches `keep` (indices into table, in that order), with their records and inputs."""
    rec = concat_ranges((np.cumsum(table[:, 3]) - table[:, 3])[keep], table[keep, 3])
    ins = concat_ranges((np.cumsum(table[:, 4]) - table[:, 4])[keep], table[keep, 4])
    return {k: v[ins] if k.startswith("in_") else v[rec] for k, v in cols.items()}, table[keep]


def input_starts(inputs: ColumnTable, n_records: int) -> np.ndarray:
    """Where each of `n_records` records' inputs start among `inputs`, and where the last ones
    end: n_records + 1 offsets. The inputs must be in their records' order, as RunRecords
    holds them (ValueError otherwise: counted offsets would give other records' inputs)."""
    out = np.zeros(n_records + 1, dtype=np.int64)
    if len(inputs):
        record = inputs["record"]
        if np.any(record[1:] < record[:-1]):
            raise ValueError("input records not in their records' order")
        np.cumsum(np.bincount(record, minlength=n_records), out=out[1:])
    return out


def concat_ranges(starts: np.ndarray, lengths: np.ndarray) -> np.ndarray:
    """The concatenation of arange(start, start + length) for each pair, without a loop."""
    shift = np.repeat(starts - (np.cumsum(lengths) - lengths), lengths)
    return shift + np.arange(int(lengths.sum()), dtype=np.int64)


def _bad_inputs(cols: dict[str, np.ndarray], table: np.ndarray) -> np.ndarray:
    """Batches with an in_record outside their own records (from each batch's
    smallest and largest in_record: no per-input temporaries)."""
    counts, ninputs = table[:, 3], table[:, 4]
    has = np.flatnonzero(ninputs > 0)
    if not len(has):
        return np.zeros(0, dtype=np.int64)
    rec = cols["in_record"]
    first = (np.cumsum(ninputs) - ninputs)[has]
    low = np.minimum.reduceat(rec, first)
    high = np.maximum.reduceat(rec, first)
    return has[(low < 0) | (high >= counts[has])].astype(np.int64)


def _records(cols: dict[str, np.ndarray], table: np.ndarray) -> ColumnTable:
    """The decoder's columns as they are (RECORD_DTYPE has the wire's types: no copy)."""
    counts = table[:, 3]
    out = {
        "dpu": np.repeat(table[:, 0].astype(RECORD_DTYPE["dpu"]), counts),
        "process": cols["process"],
        **{name: cols[name] for name in CYCLE_FIELDS},
        "flags": cols["flags"],
    }
    # Their batch's, repeated for each record only when read (a report of one generation
    # reads neither).
    per_batch = {"generation": table[:, 1], "batch_seq": table[:, 2]}
    return ColumnTable.of(out, RECORD_DTYPE, derive={name: partial(np.repeat, values, counts)
                                                     for name, values in per_batch.items()})  # fmt: skip


def _inputs(cols: dict[str, np.ndarray], table: np.ndarray) -> ColumnTable:
    if not len(table) or not len(cols["in_record"]):
        return ColumnTable.empty(INPUT_DTYPE)
    # in_record is relative to its batch: add the batch's first record index.
    first_record = np.cumsum(table[:, 3]) - table[:, 3]
    index = np.repeat(first_record, table[:, 4]) + cols["in_record"]
    wire = {name: cols[f"in_{name}"] for name in ("buffer", "seq", "new", "dropped", "received", "sent_ns",
                                                   "recv_ns")}  # fmt: skip
    # The inputs go in their records' order, so a record's are one run of rows (input_starts). A
    # DPU lists them so; a batch that does not (the wire allows it) is put in order here.
    if np.any(index[1:] < index[:-1]):
        order = np.argsort(index, kind="stable")
        index, wire = index[order], {name: column[order] for name, column in wire.items()}
    out = {"record": index, "process": cols["process"][index], **wire}
    # Their record's, made only when read (the report reads the cycle of a few).
    derive = {"dpu": partial(np.repeat, table[:, 0], table[:, 4]),
              "cycle": partial(cols["cycle"].take, index)}
    return ColumnTable.of(out, INPUT_DTYPE, derive=derive)


SeqRanges = dict[int, list[tuple[int, int]]]  # DPU -> its batch_seqs heard, as sorted inclusive runs


def seq_ranges(dpu: np.ndarray, batch_seq: np.ndarray) -> SeqRanges:
    """Each DPU's batch_seqs (any order, repeats allowed) as sorted runs of consecutive ones."""
    out: SeqRanges = {}
    for d in np.unique(dpu).tolist():
        seqs = np.unique(batch_seq[dpu == d])
        breaks = np.flatnonzero(np.diff(seqs) > 1)
        firsts, lasts = np.r_[seqs[:1], seqs[breaks + 1]], np.r_[seqs[breaks], seqs[-1:]]
        out[int(d)] = list(zip(firsts.tolist(), lasts.tolist(), strict=True))
    return out


def lost_batches(
    dpu: np.ndarray, batch_seq: np.ndarray, expected: dict[int, int] | None = None
) -> list[dict[str, int]]:
    """Gaps in each DPU's batch_seq (which runs from 0): [{dpu, from_seq, to_seq}], inclusive."""
    return lost_in_ranges(seq_ranges(dpu, batch_seq), expected)


def lost_in_ranges(ranges: SeqRanges, expected: dict[int, int] | None = None) -> list[dict[str, int]]:
    """lost_batches of the batch_seqs heard as `ranges`; `expected`: DPU -> the batches it
    published, by its own count (its report_t), for those lost at the end."""
    lost: list[dict[str, int]] = []
    for d in sorted(set(ranges) | set((expected or {}).keys())):
        previous = -1
        for first, last in ranges.get(d, []):
            if first > previous + 1:
                lost.append({"dpu": d, "from_seq": previous + 1, "to_seq": first - 1})
            previous = last
        published = (expected or {}).get(d)
        if published is not None and published - 1 > previous:
            lost.append({"dpu": d, "from_seq": previous + 1, "to_seq": published - 1})
    return lost
