"""stopped.py: which command heard during a run stopped it early, and when."""

from __future__ import annotations

import skelmsg
from skeleton.analysis.measure.stopped import Stopped, stopped_early


def _command(kind: int, session: int, **fields: int | str) -> skelmsg.command_t:
    command = skelmsg.command_t()
    command.kind, command.session, command.sender = kind, session, f"HOST pid {session}"
    for name, value in fields.items():
        setattr(command, name, value)
    return command


def test_only_a_command_the_dpus_obey_before_the_planned_end_stops_a_run() -> None:
    """A DPU obeys STOP or SHUTDOWN during a run only from the run's session or with force;
    the host's STOP after the planned end is how every run ends. skel's commands are dated by
    their seq (its wall clock at sending), whenever they were heard."""
    at_ns, second = 1_800_000_000 * 10**9, 10**9
    start = (0, _command(skelmsg.command_t.START, 7, seq=at_ns - 2 * second, run_id=42, at_utc_ns=at_ns,
                         duration_ns=10 * second))  # fmt: skip
    stop, shutdown = skelmsg.command_t.STOP, skelmsg.command_t.SHUTDOWN
    assert stopped_early([start, (0, _command(stop, 7, seq=at_ns + 11 * second))], 42) is None
    assert stopped_early([start, (0, _command(stop, 7, seq=at_ns + 2 * second))], 43) is None
    foreign = (0, _command(stop, 8, seq=at_ns + 2 * second))
    assert stopped_early([start, foreign], 42) is None
    # Heard (replayed) an hour after it was sent: dated by its seq.
    forced = (at_ns // 1000 + 3600 * 10**6, _command(shutdown, 8, seq=at_ns + 3_500_000_000, force=1, dpu=3))
    assert stopped_early([start, foreign, forced], 42) == Stopped(
        at_s=3.5, planned_s=10.0, command="SHUTDOWN", sender="HOST pid 8", dpu=3)
    # Another tool's counter is no time: dated when heard.
    counted = (at_ns // 1000 + 4_250_000, _command(stop, 9, seq=3, force=1, dpu=-1))
    dated = stopped_early([start, counted], 42)
    assert dated is not None and dated.at_s == 4.25, dated
    # A STOP before START is another run's end; a run until STOP (duration 0) has no planned end.
    assert stopped_early([(0, _command(stop, 7, seq=at_ns - 3 * second)), start], 42) is None
    endless = (0, _command(skelmsg.command_t.START, 7, seq=at_ns, run_id=42, at_utc_ns=at_ns, duration_ns=0))
    assert stopped_early([endless, (0, _command(stop, 7, seq=at_ns + second))], 42) is None
