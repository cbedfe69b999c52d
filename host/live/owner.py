"""Whose run is it: a run belongs to the host tool that started it.

Labs are shared. Every DPU's heartbeat names the run it is in, the host tool that
started it (its session and "HOST pid N") and the run's planned end (dpu/owner.c).
Before `skel run` or `skel push` sends anything it reads those heartbeats: DPUs
busy in another session's run are a refusal, at once, naming the run, its host
and when it ends; with `--force` the run is taken over (`skel run`: stopped, then
ours starts) or pushed into (`skel push`), and the DPUs log who did it. The DPUs
refuse the same on their own, so two host tools racing each other are still kept
apart.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import skelmsg

from .control import Control

BUSY = ("armed", "running")
STOP_WAIT_S = 5.0           # a taken-over run's DPUs are idle well within this after STOP
HEAR_BEFORE_SPAWN_S = 0.5   # DPUs heartbeat at 5 Hz: before --spawn, listen this long for busy ones


@dataclass(frozen=True)
class ForeignRun:
    """Another session's run that holds some of our DPUs."""

    run_id: int
    owner: str
    end_utc_ns: int
    dpus: list[int]

    def describe(self) -> str:
        left = (self.end_utc_ns - time.time_ns()) / 1e9
        if self.end_utc_ns <= 0:
            until = "until it is stopped"
        else:
            until = time.strftime("until %H:%M:%S UTC", time.gmtime(self.end_utc_ns / 1e9))
            until += f" ({left:.0f} s from now)" if left > 0 else " (its end is past: finishing)"
        return (f"DPU {', '.join(map(str, self.dpus))} {'is' if len(self.dpus) == 1 else 'are'} in run "
                f"{self.run_id} of {self.owner or 'another host tool'}, {until}")


def foreign_runs(control: Control, dpu_ids: list[int]) -> list[ForeignRun]:
    """The runs of other sessions that the heartbeats show among `dpu_ids`."""
    runs: dict[tuple[int, int], ForeignRun] = {}
    for dpu, view in sorted(control.snapshot().items()):
        status = view.status
        if dpu not in dpu_ids or view.state not in BUSY or status.run_session == control.session:
            continue
        key = (status.run_id, status.run_session)
        known = runs.get(key)
        dpus = [*known.dpus, dpu] if known else [dpu]
        runs[key] = ForeignRun(status.run_id, status.run_owner, status.run_end_utc_ns, dpus)
    return list(runs.values())


def refusal(runs: list[ForeignRun], command: str) -> str:
    """The message of a refused `skel run` / `skel push`."""
    what = "; ".join(r.describe() for r in runs)
    return (f"skel {command}: {what}: nothing was sent. Wait for its end, or `--force` to "
            + ("take it over (it is stopped, then this run starts)" if command == "run"
               else "push into it anyway"))


def take_over(control: Control, runs: list[ForeignRun], dpu_ids: list[int]) -> list[int]:
    """--force on `skel run`: stop the other runs (the DPUs log who did it) and wait
    until our DPUs are idle; return those still busy."""
    control.force = True
    for run in runs:
        for dpu in run.dpus:
            control.command(skelmsg.command_t.STOP, dpu=dpu)

    def idle() -> bool:
        return all(i not in control.dpus or control.dpus[i].state not in BUSY for i in dpu_ids)

    control.wait_for(idle, STOP_WAIT_S)
    views = control.snapshot()
    return [i for i in dpu_ids if i in views and views[i].state in BUSY]


def taken_over(control: Control, run_id: int, dpu_ids: list[int]) -> str | None:
    """During our run: who ended it, when a forced STOP or another session's run did."""
    for dpu, view in sorted(control.snapshot().items()):
        status = view.status
        if dpu not in dpu_ids:
            continue
        if status.run_id != run_id and view.state in BUSY and status.run_session != control.session:
            return f"run {run_id} was taken over by {status.run_owner or 'another host tool'} (--force)"
        if "STOP from" in status.reject_reason and f"run {run_id} " in status.reject_reason:
            return f"run {run_id} was stopped: {status.reject_reason}"
    return None
