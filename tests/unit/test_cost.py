"""bench/cost.py: what the cycle-rate part says of a frame that overran with no stall to explain it."""

from __future__ import annotations

import sys

import numpy as np
from conftest import REPO

from skeleton.analysis.read.records import RECORD_DTYPE

sys.path.insert(0, str(REPO / "bench"))
from cost import frame_hiccups_ns

US = 1000


Row = tuple[int, int, int, int]


def _frame(minor: int, wake_us: int, computes_us: list[int], gap_us: int = 0) -> list[Row]:
    """(minor, start, end, asked) ns of one frame of 100 us: its processes back to back, the
    first `gap_us` before the second."""
    at, rows = minor * 100 * US + wake_us * US, []
    for k, c in enumerate(computes_us):
        rows.append((minor, at, at + c * US, 10 * US))
        at += c * US + (gap_us * US if k == 0 else 0)
    return rows


def test_a_frame_s_hiccup_is_its_longest_stretch_lost_at_once() -> None:
    rows = (_frame(0, 4, [10, 10, 10]) + _frame(1, 44, [10, 10, 10]) + _frame(2, 3, [10, 47, 10])
            + _frame(3, 2, [10, 10, 10], gap_us=38))  # fmt: skip
    recs = np.zeros(len(rows), dtype=RECORD_DTYPE)
    recs["dpu"], recs["process"] = 1, np.tile([1, 2, 3], 4)
    recs["minor"] = [r[0] for r in rows]
    recs["release_ns"] = recs["sched_ns"] = recs["minor"] * 100 * US
    recs["start_ns"] = [r[1] for r in rows]
    recs["asked_ns"] = [r[3] for r in rows]
    recs["compute_ns"] = [r[2] - r[1] for r in rows]  # the end: the start and the compute (cycle_end_ns)
    shuffled = recs[np.random.default_rng(1).permutation(len(recs))]
    ordered, first, hiccup = frame_hiccups_ns(shuffled)
    assert np.array_equal(ordered["minor"], np.repeat([0, 1, 2, 3], 3))
    assert first.tolist() == [True, False, False] * 4
    assert (hiccup // US).tolist() == [4] * 3 + [44] * 3 + [37] * 3 + [38] * 3


def test_a_stall_touches_the_jobs_queued_behind_it_at_its_priority_and_below() -> None:
    from run import stall_touched  # bench/run.py

    ms = 1_000_000
    # process, release, start, its computation (ms), its own stall (ms), the ideal start (ms)
    jobs = [(1, 0, 0.0, 3.0, 1.0, 0.0),        # stalled 1 ms: ended at 3 ms instead of 2
            (2, 0, 3.0, 1.0, 0.0, 2.0),        # queued behind it: touched
            (3, 0, 4.0, 6.0, 0.0, 3.0),        # queued behind that one (due after the first): touched
            (1, 5, 5.001, 1.0, 0.0, 5.0),      # preempts the stalled job below it: not touched
            (2, 10, 10.002, 1.0, 0.0, 10.0),   # ran while the job below ended: not touched
            (3, 25, 25.001, 1.0, 0.0, 25.0)]   # nothing stalled since: not touched
    recs = np.zeros(len(jobs), dtype=RECORD_DTYPE)
    recs["process"] = [j[0] for j in jobs]
    recs["release_ns"] = [j[1] * ms for j in jobs]
    recs["start_ns"] = [round(j[2] * ms) for j in jobs]
    recs["compute_ns"] = [round(j[3] * ms) for j in jobs]
    recs["stall_ns"] = [round(j[4] * ms) for j in jobs]
    ideal = np.array([round(j[5] * ms) for j in jobs], dtype=np.int64)
    touched = stall_touched(recs, ideal, [5000, 10000, 25000])
    assert touched.tolist() == [True, True, True, False, False, False]
