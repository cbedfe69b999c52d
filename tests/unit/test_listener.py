"""host/live/listener.py: one live listener. `skel watch`, `skel run` and `skel report` name the same
faults of the same run (one definition); the listener's faults are the report's; a DPU is lost
after LOST_AFTER_S without a heartbeat, and each fault is said once."""

from __future__ import annotations

import re
import time

from analysis_synth import RUN_ID, batches, small_config, small_run, status

import skelmsg
from skeleton.analysis.measure.report import build_report
from skeleton.analysis.read.records import decode_run
from skeleton.host.live.listener import LOST_AFTER_S, Listener, fault_line
from skelmsg.contract import COMMAND_CHANNEL, CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL


def _heard(listener: Listener) -> None:
    listener.handle(CONFIG_CHANNEL, small_config().encode())
    listener.handle(STATUS_CHANNEL, status(2, [(2, 1, 7)]).encode())
    dpu1, dpu2 = small_run()
    for t in batches(1, dpu1, 3) + batches(2, dpu2, 2):
        listener.handle(TIMING_CHANNEL, t.encode())


def test_the_listeners_faults_are_the_reports_and_said_once() -> None:
    listener = Listener()
    listener.follow(RUN_ID)
    _heard(listener)
    found = listener.new_faults(running=False)
    dpu1, dpu2 = small_run()
    messages = [t.encode() for t in batches(1, dpu1, 3) + batches(2, dpu2, 2)]
    expected = build_report(small_config(), decode_run(messages, RUN_ID), [status(2, [(2, 1, 7)])]).faults
    assert [fault_line(f) for f in found] == [fault_line(f) for f in expected]
    assert any(f.kind == "lockout" for f in found)
    assert "lockout: C (DPU 2) at cycle 7, waiting on b_out" in fault_line(found[0])
    _heard(listener)  # heard again (re-sent): nothing new to say
    assert listener.new_faults(running=False) == []
    assert [text for _, text in listener.faults] == [fault_line(f) for f in found]


def test_a_dpu_is_lost_after_lost_after_s_without_a_heartbeat() -> None:
    listener = Listener()
    listener.follow(RUN_ID)
    _heard(listener)
    listener.handle(STATUS_CHANNEL, status(1, []).encode())
    deadline = time.monotonic() + LOST_AFTER_S + 0.2
    while time.monotonic() < deadline:  # DPU 2 heartbeats, DPU 1 is silent
        listener.handle(STATUS_CHANNEL, status(2, []).encode())
        time.sleep(0.05)
    assert listener.lost([1, 2]) == [1]
    lost = [f for f in listener.new_faults(running=True) if f.kind == "dpu_lost"]
    assert [f.dpu for f in lost] == [1]
    line = fault_line(lost[0])
    assert re.fullmatch(r"dpu_lost: DPU 1 not heard for 0\.[6-9]\d s", line), line
    listener.handle(STATUS_CHANNEL, b"junk")   # a malformed message is counted, not a crash
    assert listener.malformed == {STATUS_CHANNEL: 1}


def test_a_lockout_repeated_by_heartbeats_does_not_make_the_search_due_again() -> None:
    """Each heartbeat repeats its DPU's lockouts: only one not heard before brings the next
    search for faults forward; otherwise it waits FAULTS_COST_FACTOR times the last one's cost."""
    listener = Listener()
    listener.follow(RUN_ID)
    _heard(listener)
    listener.timed_search(lambda: time.sleep(0.2))
    assert not listener.faults_due()
    for _ in range(5):
        listener.handle(STATUS_CHANNEL, status(2, [(2, 1, 7)]).encode())  # the lockout _heard sent
    assert not listener.faults_due()
    listener.handle(STATUS_CHANNEL, status(1, [(0, -1, 9)]).encode())
    assert listener.faults_due()


def test_a_report_of_a_run_no_longer_followed_says_nothing() -> None:
    """A search for faults begun before the listener followed a newer run hands in the old
    run's report: its faults are not the new run's."""
    listener = Listener(auto_follow=True)
    listener.follow(RUN_ID)
    _heard(listener)
    old = listener.report()
    assert old is not None and old.faults
    dpu1, _ = small_run()
    listener.handle(TIMING_CHANNEL, batches(1, dpu1, 3, run_id=RUN_ID + 1)[0].encode())
    assert listener.run_id == RUN_ID + 1
    assert listener.announce(old, running=False) == [] and listener.faults == []


def test_progress_is_the_runs_start_and_its_dpus_clocks_while_running() -> None:
    """How far the followed run has come (the console shows it): from its START, heard on the
    record URL as a log replays it, to the newest clock of a DPU heartbeating while running it. A
    heartbeat after the run (ready) does not move it on; it never passes the planned length."""
    at_ns = 1_700_000_000 * 10**9
    listener = Listener()
    listener.follow(RUN_ID)

    def beat(dpu: int, after_s: float, state: int = skelmsg.status_t.STATE_RUNNING) -> None:
        s = status(dpu, [])
        s.state, s.utc_ns = state, at_ns + round(after_s * 1e9)
        listener.handle(STATUS_CHANNEL, s.encode())

    def start(run_id: int, duration_s: float) -> bytes:
        c = skelmsg.command_t()
        c.kind, c.run_id, c.at_utc_ns, c.duration_ns, c.sender = (
            skelmsg.command_t.START, run_id, at_ns, round(duration_s * 1e9), "HOST pid 1")
        return c.encode()

    beat(1, 0.2)
    assert listener.progress() is None  # no START heard
    listener.handle(COMMAND_CHANNEL, start(RUN_ID, 2.0))
    assert listener.progress() == (0.2, 2.0)
    beat(2, 1.5)
    beat(1, 1.4)  # the DPUs' newest clock counts
    assert listener.progress() == (1.5, 2.0)
    beat(1, 9.0, skelmsg.status_t.STATE_READY)
    assert listener.progress() == (1.5, 2.0)
    beat(2, 3.0)
    assert listener.progress() == (2.0, 2.0)
    listener.handle(COMMAND_CHANNEL, start(RUN_ID, 0.0))  # until STOP
    assert listener.progress() == (3.0, None)
    listener.handle(COMMAND_CHANNEL, start(0, 1.0))  # no run id: refused, counted
    assert listener.malformed == {COMMAND_CHANNEL: 1}
