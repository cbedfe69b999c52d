"""tests/e2e/test_repair_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

from skeleton.host.live.repair import SeenBatches, seq_ranges


def test_holes_are_found_below_the_newest_batch_and_up_to_the_reported_count() -> None:
    seen = SeenBatches()
    for seq in (0, 1, 4, 2, 7):
        seen.add(seq)
    assert (seen.whole, seen.has(4), seen.has(5)) == (3, True, False)
    assert seen.missing(None) == [3, 5, 6]  # the tail after 7 is unknown until the report
    assert seen.missing(10) == [3, 5, 6, 8, 9]
    assert seq_ranges([3, 5, 6, 8, 9]) == [(3, 3), (5, 6), (8, 9)]
