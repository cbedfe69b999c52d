"""Clock offsets: the four-timestamp arithmetic, and real DPUs with an injected offset (ttl=0)."""

from __future__ import annotations

from skeleton.host.live import clock
from skeleton.host.live.control import PingSample


def test_offset_and_round_trip_from_four_timestamps() -> None:
    # The DPU runs 5 ms ahead; 100 µs each way, 30 µs in the DPU.
    t1 = 1_000_000
    sample = PingSample(t1, t1 + 100_000 + 5_000_000, t1 + 130_000 + 5_000_000, t1 + 230_000)
    assert sample.offset_ns == 5_000_000
    assert sample.rtt_ns == 200_000
    # An asymmetric path moves the estimate by half the difference, never more than rtt/2.
    skewed = PingSample(t1, t1 + 180_000 + 5_000_000, t1 + 210_000 + 5_000_000, t1 + 230_000)
    assert abs(skewed.offset_ns - 5_000_000) <= skewed.rtt_ns // 2


def test_best_keeps_the_shortest_round_trip_and_refuses_corrupt_echoes() -> None:
    quick = PingSample(0, 1_050, 1_060, 100)       # rtt 90, offset 1005
    slow = PingSample(0, 3_000, 3_010, 5_000)      # rtt 4990
    corrupt = PingSample(0, 1_000, 9_000, 100)     # DPU "took" longer than the round trip
    found = clock.best(7, [slow, corrupt, quick])
    assert found is not None
    assert (found.dpu, found.offset_ns, found.rtt_ns, found.samples) == (7, 1_005, 90, 2)
    assert clock.best(7, [corrupt]) is None
    assert clock.best(7, []) is None
