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
