"""Clock offsets: the four-timestamp arithmetic, and real DPUs with an injected offset (ttl=0)."""

from __future__ import annotations

import json
import threading

import lcm
from conftest import DpuFarm, fresh_url, skel

import skelmsg
from skeleton.host.live import clock
from skeleton.host.live.control import Control, PingSample
from skeleton.host.sysfile.link import record_url
from skelmsg.contract import CLOCK_CHANNEL

TOLERANCE_NS = 200_000


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


def test_estimate_recovers_injected_offsets_and_publishes_them(dpus: DpuFarm, url: str) -> None:
    dpus.start(1, extra=["--clock-offset-ns", "5000000"])
    dpus.start(2, extra=["--clock-offset-ns", "-3000000"])
    dpus.start(3)
    heard: list[skelmsg.clock_offset_t] = []
    listener = lcm.LCM(record_url(url))  # the logger's URL: clock estimates are for the log
    listener.subscribe(CLOCK_CHANNEL, lambda _c, data: heard.append(skelmsg.clock_offset_t.decode(data)))
    control = Control(url)
    try:
        assert control.wait_heard([1, 2, 3], 5.0) == []
        keeper = clock.ClockKeeper(control, [1, 2, 3, 99])  # 99 does not exist: skipped, no hang
        found = keeper.refresh()
        assert sorted(found) == [1, 2, 3]
        for dpu, injected in ((1, 5_000_000), (2, -3_000_000), (3, 0)):
            assert abs(found[dpu].offset_ns - injected) < TOLERANCE_NS, found[dpu]
            assert 0 <= found[dpu].rtt_ns < 1_000_000_000, found[dpu]
            assert found[dpu].samples >= 1
        assert not keeper.due()
        thread = threading.Thread(target=lambda: [listener.handle_timeout(100) for _ in range(10)])
        thread.start()
        thread.join()
        assert {m.dpu: m.offset_ns for m in heard} == {d: e.offset_ns for d, e in found.items()}
        # No ping is left waiting for answers (the table would grow over a long run).
        assert control.pongs([]) == {} and not control._pings
    finally:
        control.close()


def test_skel_clock_command(dpus: DpuFarm, url: str) -> None:
    dpus.start(4, extra=["--clock-offset-ns", "2500000"])
    result = skel("clock", "--url", url, "--json")
    assert result.returncode == 0, result.stdout + result.stderr
    rows = {r["dpu"]: r for r in json.loads(result.stdout)}
    assert abs(rows[4]["offset_ns"] - 2_500_000) < TOLERANCE_NS, rows
    table = skel("clock", "--url", url)
    assert table.returncode == 0 and "offset" in table.stdout, table.stdout + table.stderr
    empty = fresh_url()  # a private port no DPU listens on
    nobody = skel("clock", "--url", empty, "--wait", "0.3")
    assert nobody.returncode == 1 and "no DPU" in nobody.stdout + nobody.stderr
