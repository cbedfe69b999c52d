"""Whether a run was stopped before its planned end, from the commands in its log.

`skel run` says "interrupted" on its console when Ctrl-C, SIGTERM or `run.stop_on` ends a
run early, but a report is made from the log alone, later and elsewhere: the log holds the
START (its run_id, the release of cycle 0 and how long the run was to last) and every STOP
or SHUTDOWN sent, each with the session that sent it. A DPU obeys one during a run only from
the run's own session, or with `force`; one sent before the planned end stopped the run.

When it was sent: `skel` numbers its commands by its wall clock at sending (command_t.seq),
the clock START's instants are on, so a replay heard long after the run (`skel watch --once`
of lcm-logplayer) dates it as the log does. A command numbered otherwise (another tool's
counter) is dated when it was heard.
"""

from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from typing import Any

import skelmsg

_ENDS = (skelmsg.command_t.STOP, skelmsg.command_t.SHUTDOWN)
_NAMES = {skelmsg.command_t.STOP: "STOP", skelmsg.command_t.SHUTDOWN: "SHUTDOWN"}
# A START whose seq lies this close to the release it names was numbered by a wall clock
# (skel's lead is seconds).
CLOCKED_WITHIN_NS = 3600 * 10**9


@dataclass(frozen=True)
class Stopped:
    """A run ended by a command before its planned end."""

    at_s: float  # when the command was sent, from the release of cycle 0
    planned_s: float  # how long the run was to last
    command: str  # STOP or SHUTDOWN
    sender: str  # who sent it ("HOST pid N")
    dpu: int = -1  # the one DPU it stopped (the others ran on); -1: every DPU


def stopped_early(commands: Iterable[tuple[int, Any]], run_id: int) -> Stopped | None:
    """The first command that ended run `run_id` before its planned end, from the log's
    (utime_us heard, command_t) in log order; None when the run ran its course, had no
    planned end (duration 0: until STOP) or its START is not in the log."""
    start = None
    for utime_us, command in commands:
        if start is None:
            if command.kind == skelmsg.command_t.START and command.run_id == run_id:
                if not command.duration_ns:
                    return None
                start = command
            continue
        if command.kind not in _ENDS or not (command.session == start.session or command.force):
            continue
        clocked = abs(start.seq - start.at_utc_ns) < CLOCKED_WITHIN_NS and command.seq >= start.seq
        at_ns = (command.seq if clocked else utime_us * 1000) - start.at_utc_ns
        if at_ns < start.duration_ns:
            return Stopped(at_s=max(0, at_ns) / 1e9, planned_s=start.duration_ns / 1e9,
                           command=_NAMES[command.kind], sender=command.sender, dpu=max(-1, command.dpu))
        return None  # the first one after the planned end: the host ending a run that ran its course
    return None
