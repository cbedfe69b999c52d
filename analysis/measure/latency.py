"""Per-buffer transport latency and loss, and the clock offsets that make
cross-host times comparable.

Transport latency of a buffer at one reader: for every reader cycle that found a
new sequence (in_new = 1), the newest message's receive time (reader's DPU clock)
minus its send time (writer's DPU clock), both moved to the host clock with the
clock-offset estimates in the log (channel SKEL_CLOCK, clock_offset_t: offset_ns =
DPU clock - host clock). A time t on DPU d is taken as t - offset, with the latest
estimate for d made at or before t (its host_mono_ns + offset_ns on d's clock);
before d's first estimate, the first one; a DPU with no estimate has offset 0 (one
machine, one clock). An estimate is off by at most half its round trip, so one
with |offset_ns| <= rtt_ns / 2 cannot tell the DPU's clock from the host's: it is
taken as 0. That is the one-machine case (the monotonic clocks of two hosts differ
by their boot times, far more than any round trip), where a ping's queueing would
otherwise shift every latency by tens of µs. Stale cycles hold the same message as before and are not
counted again, so each sequence contributes at most one sample per reader.

Loss at one reader, over the measured window (completed cycles):
- new: cycles that found a newer sequence; each such cycle uses exactly one message.
- dropped: sequences skipped between two used ones (Σ in_dropped). A skipped
  sequence was either never sent (its writer, a data-synchronised process, skipped
  that release: a RELEASE_SKIPPED record of the writer's, cycle k being sequence k),
  received and superseded before the reader ran (the writer is faster than the
  reader), or never received (lost on the link).
- unpublished: the dropped sequences that were never sent.
- received: messages received (Σ in_received), including superseded ones.
- superseded = received - new: received but never used (overwritten by a newer one
  before the reader's next cycle, or arriving late and out of order).
- lost = max(0, dropped - unpublished - superseded): sequences sent and never received.
  A reader that ran and never received one (no gap to count) lost every sequence published
  (a full bus queue can starve a buffer whole).
A buffer's `published` is the number of its writer's completed measured cycles (a
cycle k publishes sequence k on every output).

Like metrics.py, everything here takes record arrays and the window's System, never a file.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

from skeleton.host.model import System

from ..read.records import FLAG_RELEASE_SKIPPED
from .metrics import InputMetrics, InputPairs, completed, input_pairs, rows_by_process, window_mask
from .stats import Histogram, LatencyUs, distribution, group_slices, latency_us


class ClockOffsets:
    """Per-DPU clock-offset estimates (offset_ns = DPU clock - host clock)."""

    def __init__(self, estimates: Iterable[tuple[int, ...]] = ()) -> None:
        """`estimates`: (dpu, host_mono_ns, offset_ns[, rtt_ns]) in any order."""
        by_dpu: dict[int, list[tuple[int, int]]] = {}
        for dpu, host_ns, offset_ns, *rtt in estimates:
            offset = _significant(int(offset_ns), int(rtt[0]) if rtt else 0)
            by_dpu.setdefault(int(dpu), []).append((int(host_ns) + int(offset_ns), offset))
        self._at: dict[int, tuple[np.ndarray, np.ndarray]] = {}
        for dpu, rows in by_dpu.items():
            rows.sort()
            self._at[dpu] = (
                np.array([r[0] for r in rows], dtype=np.int64),
                np.array([r[1] for r in rows], dtype=np.int64),
            )
        # The DPUs with an estimate past its error: those on the host's own machine have none, and
        # their times need no search among the estimates (2 s of CPU in a profile of the report
        # of 10^7 records: its user time 15.9-17.3 s so, 16.2-18.9 s before).
        self._off = {dpu for dpu, (_, offset) in self._at.items() if offset.any()}

    @classmethod
    def from_messages(cls, messages: Iterable[Any]) -> ClockOffsets:
        """From decoded clock_offset_t messages."""
        return cls((m.dpu, m.host_mono_ns, m.offset_ns, m.rtt_ns) for m in messages)

    @property
    def dpus(self) -> list[int]:
        return sorted(self._at)

    def latest(self) -> dict[int, int]:
        """DPU -> its last estimate as applied (ns; 0 when within its error)."""
        return {dpu: int(offset[-1]) for dpu, (_, offset) in sorted(self._at.items())}

    def offset_ns(self, dpu: int, t_dpu_ns: np.ndarray) -> np.ndarray:
        """The offset in force at each time (on the DPU's clock)."""
        t = np.asarray(t_dpu_ns, dtype=np.int64)
        if dpu not in self._off:
            return np.zeros(t.shape, dtype=np.int64)
        when, offset = self._at[dpu]
        i = np.searchsorted(when, t, side="right") - 1
        return offset[np.maximum(i, 0)]

    def to_host(self, dpu: int, t_dpu_ns: np.ndarray) -> np.ndarray:
        t = np.asarray(t_dpu_ns, dtype=np.int64)
        return t - self.offset_ns(dpu, t) if dpu in self._off else t.copy()

    def to_host_many(self, dpus: np.ndarray, t_dpu_ns: np.ndarray) -> np.ndarray:
        """Times of several DPUs (dpus[i] is the clock of t_dpu_ns[i])."""
        t = np.asarray(t_dpu_ns, dtype=np.int64)
        out = t.copy()
        if not self._off:
            return out
        for dpu in np.unique(dpus).tolist():
            if dpu in self._off:
                mask = dpus == dpu
                out[mask] = self.to_host(dpu, t[mask])
        return out


def _significant(offset_ns: int, rtt_ns: int) -> int:
    """The offset, or 0 when the estimate's error (rtt / 2) covers it."""
    return 0 if 2 * abs(offset_ns) <= rtt_ns else offset_ns


NO_OFFSETS = ClockOffsets()


@dataclass
class ReaderMetrics:
    process: str
    latency_us: LatencyUs
    samples: int  # new cycles with a send and a receive time
    new: int
    dropped: int
    received: int
    unpublished: int  # dropped sequences the writer never sent (it skipped that release)
    superseded: int
    lost: int
    histogram: Histogram = field(default_factory=Histogram)


@dataclass
class BufferMetrics:
    buffer: str
    buffer_id: int
    writer: str
    published: int
    latency_us: LatencyUs  # over all readers' samples
    dropped: int  # over all readers
    lost: int  # over all readers
    readers: list[ReaderMetrics] = field(default_factory=list)


def carries_latency(inputs: np.ndarray) -> np.ndarray:
    """Mask of the input records with a transport latency: new data, with its send and receive
    times."""
    return (inputs["new"] != 0) & (inputs["seq"] >= 0) & (inputs["sent_ns"] != 0) & (inputs["recv_ns"] != 0)


def transport_latency_ns(
    inputs: np.ndarray, rows: np.ndarray, reader_dpu: int, writer_dpu: int, clock: ClockOffsets
) -> np.ndarray:
    """Receive minus send (host clock) of the input records `rows` (carries_latency)."""
    recv = clock.to_host(reader_dpu, inputs["recv_ns"][rows])
    sent = clock.to_host(writer_dpu, inputs["sent_ns"][rows])
    return recv - sent


def unpublished_in_gaps(gaps: np.ndarray, skipped: np.ndarray) -> int:
    """How many of the sequences input records dropped (each of `gaps`' rows, GAP: the `dropped`
    ones just before its `seq`) are among `skipped`, the sorted cycles whose release the writer
    skipped."""
    if len(gaps) == 0 or len(skipped) == 0:
        return 0
    seq = gaps["seq"]
    first = seq - gaps["dropped"]
    return int((np.searchsorted(skipped, seq) - np.searchsorted(skipped, first)).sum())


# An input record that dropped sequences: what unpublished_in_gaps needs of it.
GAP = np.dtype([("seq", "i8"), ("dropped", "i8")])
# A record of a skipped release (FLAG_RELEASE_SKIPPED): its process's sequence `cycle` never sent.
SKIP = np.dtype([("process", "i8"), ("cycle", "i8")])


def release_skips(records: np.ndarray) -> np.ndarray:
    """The skipped releases (SKIP rows) among `records`."""
    hit = records[(records["flags"] & FLAG_RELEASE_SKIPPED) != 0]
    out = np.zeros(len(hit), dtype=SKIP)
    out["process"], out["cycle"] = hit["process"], hit["cycle"]
    return out


class ReaderPart(NamedTuple):
    """One reader's inputs of one buffer, in one part of a window: the samples and gaps its
    ReaderMetrics are made from (its counts are the process table's: metrics.InputMetrics)."""

    latency_us: np.ndarray
    gaps: np.ndarray  # GAP rows


@dataclass
class BufferParts:
    """What buffer_metrics needs of a window, from one part of it (buffer_parts) or all (join):
    per (buffer, reader), its inputs; per process, its completed measured cycles (what a
    writer published)."""

    readers: dict[tuple[int, int], list[ReaderPart]] = field(default_factory=dict)
    published: dict[int, int] = field(default_factory=dict)

    @classmethod
    def join(cls, parts: Iterable[BufferParts]) -> BufferParts:
        out = cls()
        for part in parts:
            for key, mine in part.readers.items():
                out.readers.setdefault(key, []).extend(mine)
            for proc, n in part.published.items():
                out.published[proc] = out.published.get(proc, 0) + n
        return out


def buffer_parts(
    records: np.ndarray, inputs: np.ndarray, system: System, clock: ClockOffsets = NO_OFFSETS,
    in_window: np.ndarray | None = None, pairs: InputPairs | None = None,
) -> BufferParts:
    """The BufferParts of `records` (a window, or the part of it a few DPUs ran) and their
    `inputs`. `in_window`: measured(records, system), and `pairs`: the inputs' input_pairs,
    when the caller has them."""
    in_window = window_mask(records, system, in_window)
    _, by_process = rows_by_process(records, in_window & completed(records))
    pairs = input_pairs(records, inputs, system, in_window) if pairs is None else pairs
    # The inputs that count, grouped by reader and buffer: one sort of their pairs' indices. What
    # each group needs of them is found over all the inputs' columns at once, then gathered.
    order, by_pair = group_slices(pairs.at)
    index = {pair: i for i, pair in enumerate(pairs.pairs)}
    timed = carries_latency(inputs)
    dropping = (inputs["dropped"] > 0) & (inputs["seq"] >= 0)
    out = BufferParts(published={proc: _count(rows) for proc, rows in by_process.items()})
    for buf in sorted(system.buffers, key=lambda b: b.id):
        writer = system.find_process(buf.writer)
        writer_dpu = writer.dpu if writer is not None else -1
        for reader in sorted((p for p in system.processes if buf.id in p.inputs), key=lambda p: p.id):
            if reader.id not in by_process:
                continue  # not a cycle of it here: another part has its inputs
            at = order[by_pair.get(index[(int(reader.id), int(buf.id))], slice(0, 0))]
            lat_ns = transport_latency_ns(inputs, at[timed[at]], reader.dpu, writer_dpu, clock)
            gap = at[dropping[at]]
            gaps = np.zeros(len(gap), dtype=GAP)
            gaps["seq"], gaps["dropped"] = inputs["seq"][gap], inputs["dropped"][gap]
            out.readers[(buf.id, reader.id)] = [ReaderPart(lat_ns.astype(np.float64) / 1000.0, gaps)]
    return out


def buffer_metrics(parts: BufferParts, system: System, skips: np.ndarray,
                   counted: Mapping[tuple[int, int], InputMetrics]) -> list[BufferMetrics]:
    """Per buffer (by id) that has a reader, over the measured window whose
    BufferParts are `parts`. `skips`: the skipped releases (release_skips) of the whole run,
    not the window's: a gap after a live switch may hold sequences skipped before it.
    `counted`: the process table's counts of each (reader id, buffer id) input, the same
    input records (counted once, there)."""
    out = []
    for buf in sorted(system.buffers, key=lambda b: b.id):
        readers = sorted(system.readers(buf.id), key=lambda p: p.id)
        if not readers:
            continue
        writer = system.find_process(buf.writer)
        skipped = np.sort(skips["cycle"][skips["process"] == buf.writer])
        pooled: list[np.ndarray] = []
        reader_metrics = []
        for reader in readers:
            mine = parts.readers.get((buf.id, reader.id), [])
            lat_us = np.concatenate([m.latency_us for m in mine]) if mine else np.zeros(0)
            pooled.append(lat_us)
            counts = counted.get((int(reader.id), int(buf.id)))
            new, dropped, received = (counts.new, counts.dropped, counts.received) if counts else (0, 0, 0)
            superseded = max(0, received - new)
            unpublished = sum(unpublished_in_gaps(m.gaps, skipped) for m in mine)
            lost = max(0, dropped - unpublished - superseded)
            if counts is not None and counts.stale > 0 and new == received == 0:
                lost = parts.published.get(int(buf.writer), 0)
            latency, latency_histogram = distribution(lat_us)
            reader_metrics.append(
                ReaderMetrics(
                    process=reader.name,
                    latency_us=latency,
                    samples=len(lat_us),
                    new=new,
                    dropped=dropped,
                    received=received,
                    unpublished=unpublished,
                    superseded=superseded,
                    lost=lost,
                    histogram=latency_histogram,
                )
            )
        everything = np.concatenate(pooled) if pooled else np.zeros(0)
        out.append(
            BufferMetrics(
                buffer=buf.name,
                buffer_id=int(buf.id),
                writer=writer.name if writer is not None else f"process {buf.writer}",
                published=parts.published.get(int(buf.writer), 0),
                latency_us=latency_us(everything),
                dropped=sum(r.dropped for r in reader_metrics),
                lost=sum(r.lost for r in reader_metrics),
                readers=reader_metrics,
            )
        )
    return out


def _count(rows: slice) -> int:
    return rows.stop - rows.start
