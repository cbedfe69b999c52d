"""The timing records of one followed run, kept as they arrive: a live view appends each
refresh's new batches instead of decoding every batch again. Records with impossible times
(damaged or forged bytes: records.impossible) are left out and counted, as `skel report`
leaves them out of a log."""

from __future__ import annotations

import threading
import time

import numpy as np

from skeleton.analysis.read.coltable import ColumnTable
from skeleton.analysis.read.records import (
    INPUT_DTYPE,
    RECORD_DTYPE,
    RunRecords,
    decode_run,
    impossible,
    lost_batches,
    select,
    usual_sizes,
)


class RecordStore:
    """The timing records of one run, decoded batch by batch as they arrive, in numpy
    arrays grown in chunks (doubling), so a refresh costs the new batches only. One thread
    adds; any may take run() (a view of the rows added so far) meanwhile."""

    def __init__(self, run_id: int) -> None:
        self.run_id = run_id
        self.lock = threading.Lock()
        self.records = {name: np.empty(4096, dtype=RECORD_DTYPE[name]) for name in RECORD_DTYPE.names or ()}
        self.inputs = {name: np.empty(8192, dtype=INPUT_DTYPE[name]) for name in INPUT_DTYPE.names or ()}
        self.n_records = 0
        self.n_inputs = 0
        self.batch_keys: set[tuple[int, int]] = set()
        self.batch_dpu: list[int] = []
        self.batch_seq: list[int] = []
        self.generations: set[int] = set()
        self.malformed = 0
        self.duplicates = 0
        self.impossible = 0
        # What a log's span is to `skel report`: how long this run has been heard (the store is
        # made when its first batch is).
        self.heard_since_ns = time.monotonic_ns()
        # A chunk is judged against the usual sizes of the records held before it, never its own:
        # a refresh may bring one batch, and a batch made only of damaged or forged records would
        # widen its own bounds. With nothing held yet, the span alone bounds (the cost: a watch
        # begun while a DPU lags more than a minute leaves that DPU's records out, counted, until
        # the run has been heard for up to as long as that lag). The sizes are read again each
        # time the records held doubled: from a bounded sample, so amortised O(1) per record, and
        # they follow a lag that grows.
        self._usual: dict[str, float] = {}  # read at the first add (_usual_of < 0)
        self._usual_of = -1  # records held when _usual was read

    def add(self, messages: list[bytes]) -> None:
        if not messages:
            return
        chunk = decode_run(messages, self.run_id)
        with self.lock:
            self._add(chunk)

    def _add(self, chunk: RunRecords) -> None:
        self.malformed += chunk.malformed
        self.duplicates += chunk.duplicates
        rec = chunk.records
        keys = np.stack([rec["dpu"].astype(np.int64), rec["batch_seq"]], axis=1)
        fresh = np.ones(len(rec), dtype=bool)
        for dpu, seq in np.unique(keys, axis=0).tolist() if len(rec) else []:
            if (dpu, seq) in self.batch_keys:  # heard twice (re-sent or replayed twice)
                fresh &= ~((keys[:, 0] == dpu) & (keys[:, 1] == seq))
                self.duplicates += 1
            else:
                self.batch_keys.add((dpu, seq))
                self.batch_dpu.append(dpu)
                self.batch_seq.append(seq)
        if self.n_records >= 2 * self._usual_of:
            self._usual, self._usual_of = usual_sizes(self._held()), self.n_records
        # Duplicates go first, as in a log: the first copy of a batch is the one judged.
        keep = fresh.copy()
        keep[fresh] = ~impossible(rec[fresh], time.monotonic_ns() - self.heard_since_ns, self._usual)
        self.impossible += int(np.count_nonzero(fresh & ~keep))
        kept, inputs = select(rec, chunk.inputs, keep)
        inputs["record"] += self.n_records  # select's copy, or no rows
        self.records, self.n_records = _append(self.records, self.n_records, kept)
        self.inputs, self.n_inputs = _append(self.inputs, self.n_inputs, inputs)
        # Of kept records only: a forged batch's generation would otherwise name the tables'.
        self.generations.update(np.unique(kept["generation"]).tolist())

    def run(self, expected_batches: dict[int, int] | None = None) -> RunRecords:
        with self.lock:
            return self._run(expected_batches)

    def _held(self) -> ColumnTable:
        return ColumnTable({k: v[: self.n_records] for k, v in self.records.items()}, RECORD_DTYPE)

    def _run(self, expected_batches: dict[int, int] | None) -> RunRecords:
        return RunRecords(
            run_id=self.run_id,
            records=self._held(),
            inputs=ColumnTable({k: v[: self.n_inputs] for k, v in self.inputs.items()}, INPUT_DTYPE),
            batches=len(self.batch_keys),
            generations=sorted(self.generations),
            lost_batches=lost_batches(
                np.asarray(self.batch_dpu, dtype=np.int64), np.asarray(self.batch_seq, dtype=np.int64),
                expected_batches,
            ),
            malformed=self.malformed,
            duplicates=self.duplicates,
            impossible=self.impossible,
        )


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
