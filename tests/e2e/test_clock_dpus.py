"""tests/unit/test_clock.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
import threading

import lcm
from conftest import DpuFarm, fresh_url, skel

import skelmsg
from skeleton.host.live import clock
from skeleton.host.live.control import Control
from skeleton.host.sysfile.link import record_url
from skelmsg.contract import CLOCK_CHANNEL

TOLERANCE_NS = 200_000


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
