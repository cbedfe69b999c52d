"""End-to-end latency along the chains of the system file (System.chains, head first).

Lineage: a process's cycle k publishes sequence k on every output, and each input
record says which sequence of that input was current (in_seq). Between two
consecutive chain steps P[i-1] -> P[i] the value travels on the buffer P[i-1]
writes and P[i] reads (the first such in P[i]'s inputs; validation guarantees one).
From a tail cycle, in_seq on that buffer names the cycle of P[n-1] whose output
it used; that cycle's own input from P[n-2] names P[n-2]'s cycle; and so on to
the head's cycle c0, whose value the tail cycle carries.

One sample per value: a tail cycle counts when the value it carries arrives there
for the first time (its input from the last step is new, and its c0 is newer than
every earlier tail cycle's), and only when that tail cycle is completed and in
the measured window.

- birth: the head's send time of sequence c0 (send_ns of the message, as the
  second step received it: exact, on the head's DPU clock);
- first use: the start of the tail cycle's computation (start + comm_in +
  blocked): the moment the tail has the value in hand. A data-synchronised tail
  may receive it while blocked, after its cycle started, so the cycle start would
  be too early;
- latency = first use - birth, both moved to the host clock with the clock
  offsets (latency.ClockOffsets).

A tail cycle whose lineage cannot be followed (an upstream record lost with its
timing batch, or no data yet) is counted as `broken`, not as a sample.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from skeleton.host.model import Buffer, Chain, Process, System

from ..read.coltable import ColumnTable
from ..read.parallel import map_threads, table_bytes
from ..read.records import INPUT_DTYPE, RECORD_DTYPE
from .latency import NO_OFFSETS, ClockOffsets
from .metrics import completed
from .stats import Histogram, LatencyUs, distribution

_CYCLE_BITS = 40  # (process, cycle) -> one int64 key; cycles stay far below 2**40


@dataclass
class ChainSeries:
    """One sample per value reaching the tail, in tail-cycle order."""

    tail_cycle: np.ndarray  # int64
    head_cycle: np.ndarray  # int64: c0
    use_ns: np.ndarray  # int64, host clock: first use at the tail
    latency_ns: np.ndarray  # int64


@dataclass
class ChainMetrics:
    name: str
    processes: list[str]
    buffers: list[str]  # the buffer of each step, head -> tail
    latency_us: LatencyUs
    samples: int
    broken: int
    histogram: Histogram = field(default_factory=Histogram)
    series: ChainSeries | None = field(default=None, repr=False)  # API only, not in report.json


def _empty_series() -> ChainSeries:
    z = np.zeros(0, dtype=np.int64)
    return ChainSeries(z, z.copy(), z.copy(), z.copy())


class _Lookup:
    """(process, cycle) -> record index and (record, buffer) -> input row, by binary search."""

    def __init__(self, records: np.ndarray, inputs: np.ndarray, done: np.ndarray, processes: list[int],
                 buffers: list[int]) -> None:  # fmt: skip
        # Only what the chains step through: their processes' completed records and the input
        # rows on their buffers, where a system's chains name a few of its processes.
        rows = np.flatnonzero(done & np.isin(records["process"], processes))
        ids = records["process"][rows]
        keys = (ids.astype(np.int64) << _CYCLE_BITS) + records["cycle"][rows]
        self.rec_keys, self.rec_index = _sorted(keys, np.argsort(ids, kind="stable"), rows)
        on = np.flatnonzero(np.isin(inputs["buffer"], buffers))
        buffer = inputs["buffer"][on].astype(np.int64)
        ikeys = (inputs["record"][on].astype(np.int64) << 16) + (buffer & 0xFFFF)
        self.in_keys, self.in_index = _sorted(ikeys, None, on)

    @staticmethod
    def _find(keys: np.ndarray, index: np.ndarray, wanted: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        at = np.searchsorted(keys, wanted)
        clipped = np.minimum(at, max(len(keys) - 1, 0))
        found = (at < len(keys)) & (keys[clipped] == wanted) if len(keys) else np.zeros(len(wanted), bool)
        return (index[clipped] if len(keys) else np.zeros(len(wanted), np.int64)), found

    def record(self, process: int, cycles: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return self._find(self.rec_keys, self.rec_index, (np.int64(process) << _CYCLE_BITS) + cycles)

    def input(self, records: np.ndarray, buffer: int) -> tuple[np.ndarray, np.ndarray]:
        return self._find(self.in_keys, self.in_index, (records.astype(np.int64) << 16) + (buffer & 0xFFFF))


def chain_buffers(chain: Chain, system: System) -> list[int] | None:
    """The buffer of each step (len = processes - 1), None when a step has none."""
    out = []
    for up, down in zip(chain.processes[:-1], chain.processes[1:], strict=True):
        writer, reader = system.find_process(up), system.find_process(down)
        if writer is None or reader is None:
            return None
        written = set(writer.outputs)
        step = next((b for b in reader.inputs if b in written), None)
        if step is None:
            return None
        out.append(int(step))
    return out


def _sorted(keys: np.ndarray, order: np.ndarray | None, index: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(keys, index) in key order, from an `order` (None: as they are) that sorts them or
    nearly does: the records come in cycle order per process, so ordered by process (a
    radix sort of the 16-bit ids) they are sorted; the inputs come in record order. The
    full sort left, if anything is out of place, is of a nearly sorted array: numpy's is
    fast at that."""
    if order is not None:
        keys, index = keys[order], index[order]
    if len(keys) > 1 and bool(np.any(keys[1:] < keys[:-1])):
        again = np.argsort(keys, kind="stable")
        keys, index = keys[again], index[again]
    return keys, index


class _Run(NamedTuple):
    """What every chain of a window looks up: built once for all of them."""

    look: _Lookup
    done: np.ndarray  # completed(records)
    in_window: np.ndarray  # measured(records, config)

    @classmethod
    def of(cls, records: np.ndarray, inputs: np.ndarray, system: System, in_window: np.ndarray) -> _Run:
        done = completed(records)
        processes = sorted({int(p) for chain in system.chains for p in chain.processes})
        buffers = sorted({b for chain in system.chains for b in chain_buffers(chain, system) or []})
        return cls(_Lookup(records, inputs, done, processes, buffers), done, in_window)


def _chain_series(
    records: np.ndarray, inputs: np.ndarray, system: System, chain: Chain, clock: ClockOffsets, run: _Run
) -> tuple[ChainSeries, int]:
    """The samples of one chain and the number of broken tail cycles."""
    steps = chain_buffers(chain, system)
    pids = [int(p) for p in chain.processes]
    if steps is None:
        return _empty_series(), 0
    look = run.look
    tail = pids[-1]
    # Every completed tail cycle's row on the last buffer (warm-up too: it tells
    # which values the measured window saw before).
    rec_done = run.done
    tail_rows = np.flatnonzero(
        (inputs["process"] == tail) & (inputs["buffer"] == steps[-1]) & rec_done[inputs["record"]]
    )
    tail_rows = tail_rows[np.argsort(records["cycle"][inputs["record"][tail_rows]], kind="stable")]
    rows, ok = tail_rows, inputs["seq"][tail_rows] >= 0
    for i in range(len(steps) - 1, 0, -1):  # step i: pids[i] reads steps[i-1] from pids[i-1]
        rec, found = look.record(pids[i], np.where(ok, inputs["seq"][rows], 0))
        ok &= found
        rows, found = look.input(rec, steps[i - 1])
        ok &= found & (inputs["seq"][rows] >= 0)
    head_cycle = np.where(ok, inputs["seq"][rows] if len(rows) else 0, -1)
    born = inputs["sent_ns"][rows] if len(rows) else np.zeros(0, np.int64)
    # First arrival of each value: c0 newer than every earlier tail cycle's.
    earlier = np.maximum.accumulate(np.r_[-1, head_cycle[:-1]]) if len(head_cycle) else head_cycle
    first = ok & (head_cycle > earlier)
    tail_rec = inputs["record"][tail_rows]
    in_window = run.in_window[tail_rec]
    broken = int(np.count_nonzero(in_window & ~ok & (inputs["new"][tail_rows] != 0)))
    keep = first & in_window & (inputs["new"][tail_rows] != 0)  # a stale input brings nothing
    rec = records[tail_rec[keep]]
    use = clock.to_host(system.process(tail).dpu, rec["use_ns"])
    birth = clock.to_host(system.process(pids[0]).dpu, born[keep])
    return ChainSeries(rec["cycle"].astype(np.int64), head_cycle[keep], use, use - birth), broken


# What the chains read of a record and of an input record: a window's part is kept with
# these alone (ChainRecords), its other columns let go with the part. A record's use_ns is
# when its computation had its inputs in hand: start + comm_in + blocked.
CHAIN_RECORD = np.dtype([("process", RECORD_DTYPE["process"]), ("cycle", RECORD_DTYPE["cycle"]),
                         ("flags", RECORD_DTYPE["flags"]), ("use_ns", np.int64)])
CHAIN_INPUT = np.dtype([(name, INPUT_DTYPE[name])
                        for name in ("record", "process", "buffer", "seq", "sent_ns", "new")])


class ChainRecords(NamedTuple):
    """The records of a window's chain processes and their input records on the chain buffers
    ("record" indexes the former), with each record's measured(records, config): all that
    chain_metrics reads. The parts of a window (some DPUs each) join into the window's."""

    records: ColumnTable
    inputs: ColumnTable
    in_window: np.ndarray

    @classmethod
    def of(cls, records: np.ndarray, inputs: np.ndarray, system: System,
           in_window: np.ndarray) -> ChainRecords:
        processes = sorted({int(p) for chain in system.chains for p in chain.processes})
        buffers = sorted({b for chain in system.chains for b in chain_buffers(chain, system) or []})
        chosen = np.isin(records["process"], processes)
        rows = np.flatnonzero(chosen)
        on = np.flatnonzero(np.isin(inputs["buffer"], buffers)) if len(rows) else np.zeros(0, np.int64)
        on = on[chosen[inputs["record"][on]]]
        mine = inputs[on]
        ins = {name: mine[name] for name in CHAIN_INPUT.names or () if name != "record"}
        ins["record"] = np.searchsorted(rows, mine["record"])
        theirs = records[rows]
        recs = {name: theirs[name] for name in ("process", "cycle", "flags")}
        recs["use_ns"] = theirs["start_ns"] + theirs["comm_in_ns"] + theirs["blocked_ns"]
        return cls(_table(recs, CHAIN_RECORD), _table(ins, CHAIN_INPUT), in_window[rows])

    @classmethod
    def join(cls, parts: Sequence[ChainRecords]) -> ChainRecords:
        if len(parts) == 1:
            return parts[0]
        offsets = np.cumsum([0] + [len(p.records) for p in parts[:-1]])
        records = {name: np.concatenate([p.records[name] for p in parts])
                   for name in CHAIN_RECORD.names or ()}
        inputs = {name: np.concatenate([p.inputs[name] + (o if name == "record" else 0)
                                        for p, o in zip(parts, offsets, strict=True)])
                  for name in CHAIN_INPUT.names or ()}
        return cls(_table(records, CHAIN_RECORD), _table(inputs, CHAIN_INPUT),
                   np.concatenate([p.in_window for p in parts]))


def _table(columns: Any, dtype: np.dtype[Any]) -> ColumnTable:
    """A table of `dtype`'s fields from `columns`, their values held (not views of a larger table's)."""
    return ColumnTable.of({name: np.ascontiguousarray(columns[name]) for name in dtype.names or ()}, dtype)


def chain_metrics(run: ChainRecords, system: System, clock: ClockOffsets = NO_OFFSETS) -> list[ChainMetrics]:
    """Per chain of the system, in its order, from a window's ChainRecords."""
    records, inputs = run.records, run.inputs
    look = None
    if system.chains and len(inputs):
        look = _Run.of(records, inputs, system, run.in_window)

    def one(chain: Chain) -> ChainMetrics:
        if look is None:
            series, broken = _empty_series(), 0
        else:
            series, broken = _chain_series(records, inputs, system, chain, clock, look)
        lat_us = series.latency_ns.astype(np.float64) / 1000.0
        latency, latency_histogram = distribution(lat_us)
        steps = chain_buffers(chain, system) or []
        return ChainMetrics(
            name=chain.name,
            processes=[_name(system.find_process(p), f"process {p}") for p in chain.processes],
            buffers=[_name(system.find_buffer(b), f"buffer {b}") for b in steps],
            latency_us=latency,
            samples=len(lat_us),
            broken=broken,
            histogram=latency_histogram,
            series=series,
        )

    # The chains read the lookup and write nothing shared: side by side on the cores (their
    # searches and sorts release the GIL).
    return map_threads(one, system.chains, table_bytes(records, inputs))


def _name(found: Process | Buffer | None, missing: str) -> str:
    return missing if found is None else found.name
