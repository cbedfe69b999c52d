"""The timing records of one followed run, kept as they arrive: a live view appends each
refresh's new batches instead of decoding every batch again. Records with impossible times
(damaged or forged bytes: records.impossible) are left out and counted, as `skel report`
leaves them out of a log.

A run may last hours (SERVO sends 1800 records a second, 1 GB an hour), so the store keeps
only its newest records: once it holds 2 * keep, it forgets the oldest down to the newest
`keep`, but never one its readers have not read yet (the live tables: `tallied`; the search
for faults: `searched`). Readers that fall behind by HARD_FACTOR * keep lose the records
past that, counted (`unread`). What spans the whole run stays whole: each DPU's first
release (the origin of a fault's time), its batches heard, as runs of batch_seq, and the
counts."""

from __future__ import annotations

import bisect
import math
import threading
import time

import numpy as np

from skeleton.analysis.measure.faults import first_release_ns
from skeleton.analysis.read.coltable import ColumnTable
from skeleton.analysis.read.records import (
    INPUT_DTYPE,
    RECORD_DTYPE,
    RunRecords,
    SeqRanges,
    decode_run,
    impossible,
    lost_in_ranges,
    select,
    usual_sizes,
)

KEEP_RECORDS = 1 << 17  # 73 s of SERVO; ~70 MB of arrays with their inputs and room to grow
HARD_FACTOR = 4


class RecordStore:
    """The timing records of one run, decoded batch by batch as they arrive, in numpy
    arrays grown in chunks (doubling), so a refresh costs the new batches only. One thread
    adds; any may take run() (a view of the rows held) meanwhile: forgetting copies the rows
    kept into new arrays, so a view taken before stays whole."""

    def __init__(self, run_id: int, keep: int = KEEP_RECORDS) -> None:
        self.run_id = run_id
        self.keep = keep
        self.lock = threading.Lock()
        self.records = {name: np.empty(4096, dtype=RECORD_DTYPE[name]) for name in RECORD_DTYPE.names or ()}
        self.inputs = {name: np.empty(8192, dtype=INPUT_DTYPE[name]) for name in INPUT_DTYPE.names or ()}
        self.first = 0  # records heard before the first one held (forgotten)
        self.n_held = 0
        self.n_inputs = 0
        self.seqs: SeqRanges = {}  # every batch heard, per DPU
        self.batches = 0
        self.origin_ns: dict[int, int] = {}  # each DPU's first release, of every record heard
        self.generations: set[int] = set()
        self.malformed = 0
        self.duplicates = 0
        self.impossible = 0
        # Where the readers are, in records heard: forgetting waits for them (None: no such reader).
        self.tallied: int | None = None
        self.searched = 0
        self.unread = 0  # records forgotten before a reader read them (it fell HARD_FACTOR * keep behind)
        self.held_from_ns: int | None = None  # once some are forgotten: the first release held
        # What a log's span is to `skel report`: how long this run has been heard (the store is
        # made when its first batch is).
        self.heard_since_ns = time.monotonic_ns()
        # A chunk is judged against the usual sizes of the records held before it, never its own:
        # a refresh may bring one batch, and a batch made only of damaged or forged records would
        # widen its own bounds. With nothing held yet, the span alone bounds (the cost: a watch
        # begun while a DPU lags more than a minute leaves that DPU's records out, counted, until
        # the run has been heard for up to as long as that lag). The sizes are read again each
        # time the records heard doubled: from a bounded sample, so amortised O(1) per record, and
        # they follow a lag that grows.
        self._usual: dict[str, float] = {}  # read at the first add (_usual_of < 0)
        self._usual_of = -1  # records heard when _usual was read

    @property
    def n_records(self) -> int:
        """Records heard (and kept: not impossible, not a duplicate), held or forgotten."""
        return self.first + self.n_held

    def add(self, messages: list[bytes]) -> None:
        if not messages:
            return
        chunk = decode_run(messages, self.run_id)
        with self.lock:
            self._add(chunk)
            if self.n_held > HARD_FACTOR * self.keep:  # the readers fell behind: forget anyway
                cut = self.n_records - self.keep
                self.unread += cut - max(self.first, min(self._read(), cut))
                self._forget(cut)

    def _add(self, chunk: RunRecords) -> None:
        self.malformed += chunk.malformed
        self.duplicates += chunk.duplicates
        rec = chunk.records
        keys = np.stack([rec["dpu"].astype(np.int64), rec["batch_seq"]], axis=1)
        fresh = np.ones(len(rec), dtype=bool)
        for dpu, seq in np.unique(keys, axis=0).tolist() if len(rec) else []:
            if not _heard_first(self.seqs.setdefault(dpu, []), seq):  # heard twice (re-sent, replayed twice)
                fresh &= ~((keys[:, 0] == dpu) & (keys[:, 1] == seq))
                self.duplicates += 1
            else:
                self.batches += 1
        if self.n_records >= 2 * self._usual_of:
            self._usual, self._usual_of = usual_sizes(self._held()), self.n_records
        # Duplicates go first, as in a log: the first copy of a batch is the one judged.
        keep = fresh.copy()
        keep[fresh] = ~impossible(rec[fresh], time.monotonic_ns() - self.heard_since_ns, self._usual)
        self.impossible += int(np.count_nonzero(fresh & ~keep))
        kept, inputs = select(rec, chunk.inputs, keep)
        inputs["record"] += self.n_held  # select's copy, or no rows
        self.records, self.n_held = _append(self.records, self.n_held, kept)
        self.inputs, self.n_inputs = _append(self.inputs, self.n_inputs, inputs)
        # Of kept records only: a forged batch's generation would otherwise name the tables'.
        self.generations.update(np.unique(kept["generation"]).tolist())
        for dpu, release in first_release_ns(kept).items():
            self.origin_ns[dpu] = min(release, self.origin_ns.get(dpu, release))

    def forget(self) -> None:
        """Forget the oldest records the readers are done with, once 2 * keep are held,
        down to the newest `keep` (amortised O(1) per record)."""
        with self.lock:
            if self.n_held >= 2 * self.keep:
                self._forget(min(self._read(), self.n_records - self.keep))

    def _read(self) -> int:
        """Records heard that every reader has read."""
        return self.searched if self.tallied is None else min(self.searched, self.tallied)

    def _forget(self, cut: int) -> None:
        """Forget the records heard before the `cut`-th, and their inputs."""
        drop = cut - self.first
        if drop <= 0:
            return
        inputs_cut = int(np.searchsorted(self.inputs["record"][: self.n_inputs], drop))
        self.records, self.n_held = _kept(self.records, drop, self.n_held)
        self.inputs, self.n_inputs = _kept(self.inputs, inputs_cut, self.n_inputs)
        self.inputs["record"][: self.n_inputs] -= drop
        self.first = cut
        self.held_from_ns = int(self.records["release_ns"][: self.n_held].min(initial=np.iinfo(np.int64).max))

    def run(self, expected_batches: dict[int, int] | None = None) -> RunRecords:
        with self.lock:
            return self._run(expected_batches)

    def _held(self) -> ColumnTable:
        return ColumnTable({k: v[: self.n_held] for k, v in self.records.items()}, RECORD_DTYPE)

    def _run(self, expected_batches: dict[int, int] | None) -> RunRecords:
        held = self._held()
        # Once some are forgotten, the generations are the held records' own: a report's windows.
        generations = self.generations if not self.first else set(np.unique(held["generation"]).tolist())
        return RunRecords(
            run_id=self.run_id,
            records=held,
            inputs=ColumnTable({k: v[: self.n_inputs] for k, v in self.inputs.items()}, INPUT_DTYPE),
            batches=self.batches,
            generations=sorted(generations),
            lost_batches=lost_in_ranges(self.seqs, expected_batches),
            malformed=self.malformed,
            duplicates=self.duplicates,
            impossible=self.impossible,
            first=self.first,
            origin_ns=dict(self.origin_ns),
        )


def _heard_first(runs: list[tuple[int, int]], seq: int) -> bool:
    """Add `seq` to a DPU's sorted runs of batch_seqs heard; False if it was heard before.
    Batches come mostly in order, so the search ends near the last run."""
    i = bisect.bisect_right(runs, (seq, math.inf)) - 1  # the run starting at or before seq
    if i >= 0 and runs[i][1] >= seq:
        return False
    joins_left = i >= 0 and runs[i][1] == seq - 1
    joins_right = i + 1 < len(runs) and runs[i + 1][0] == seq + 1
    if joins_left and joins_right:
        runs[i : i + 2] = [(runs[i][0], runs[i + 1][1])]
    elif joins_left:
        runs[i] = (runs[i][0], seq)
    elif joins_right:
        runs[i + 1] = (seq, runs[i + 1][1])
    else:
        runs.insert(i + 1, (seq, seq))
    return True


def _kept(columns: dict[str, np.ndarray], drop: int, used: int) -> tuple[dict[str, np.ndarray], int]:
    """Rows drop..used of `columns` in new arrays of twice their number (room to grow to the
    next forgetting without a copy, and no more: a burst that grew the old ones is let go);
    views taken before keep the old ones."""
    rows = used - drop
    out = {}
    for name, array in columns.items():
        kept = np.empty(max(2 * rows, 4096), dtype=array.dtype)
        kept[:rows] = array[drop:used]
        out[name] = kept
    return out, rows


def _append(
    columns: dict[str, np.ndarray], used: int, rows: ColumnTable
) -> tuple[dict[str, np.ndarray], int]:
    """Append rows, doubling the capacity when full (amortised O(1) per row). Rows
    below `used` are never written again, so earlier snapshots (views) stay valid."""
    need = used + len(rows)
    out = {}
    for name, array in columns.items():
        if need > len(array):
            grown = np.empty(max(need, 2 * len(array)), dtype=array.dtype)
            grown[:used] = array[:used]
            array = grown
        array[used:need] = rows[name]
        out[name] = array
    return out, need
