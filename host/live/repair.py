"""Keeping the run's log whole: ask the DPUs again for what lcm-logger missed.

lcm-logger subscribes with LCM's default queue of 30 messages and, when its
process falls behind on a busy machine, silently drops the newest. Each DPU
keeps what it published this run (dpu/history.c, a bounded ring); this module
reads the log as it grows, finds the holes in each DPU's batch_seq (and, at the
end, the batches after the last one logged and any report_t not logged), and
asks for them with RESEND. It asks a few at a time, so the repair is not itself
a burst the logger drops. What cannot be had again stays a lost batch in the
report's integrity section: the repair hides nothing.

The logger is the host tool's own child, so its death is seen at once
(LoggerKeeper): the log is cut back to its last whole event and a new logger
appends to the same file (the analysis reads one file per run), and the repair
asks the DPUs for everything published meanwhile. A logger that cannot be kept
alive, or holes that stay, make the run's log incomplete: `skel run` says so
first and exits non-zero.
"""

from __future__ import annotations

import os
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import skelmsg
from skeleton.analysis.read.logreader import read_bytes
from skeleton.analysis.read.records import timing_heads
from skelmsg.contract import REPORT_CHANNEL

from . import spawn
from .control import Control

# Batches asked for per round, over all DPUs. Like TCP's window: it starts well under the
# logger's queue of 30, doubles while every ask arrives and halves when one is lost again.
ASK_FIRST, ASK_MIN, ASK_MAX = 16, 4, 512
ROUND_S = 0.25          # the logger writes what it heard within its 100 ms flush interval
POLL_EVERY_S = 0.5      # during the run
# A DPU numbers its batches 0, 1, 2...: a batch_seq (or a report's count) this far past what
# the log holds is a stray message's, and counting the holes up to it would never end.
SEQ_AHEAD_MAX = 1 << 20


@dataclass
class SeenBatches:
    """The batch_seqs of one DPU seen in the log: all below `whole`, plus `above`."""

    whole: int = 0
    above: set[int] = field(default_factory=set)

    def add(self, seq: int) -> None:
        if self.whole <= seq < self.whole + SEQ_AHEAD_MAX:
            self.above.add(seq)
        while self.whole in self.above:
            self.above.remove(self.whole)
            self.whole += 1

    def has(self, seq: int) -> bool:
        return seq < self.whole or seq in self.above

    def missing(self, published: int | None) -> list[int]:
        """Holes below the newest seen, and up to `published` (report_t's count) when known."""
        end = max(self.above, default=self.whole - 1) + 1
        if published is not None and published <= self.whole + SEQ_AHEAD_MAX:
            end = max(end, published)
        return [s for s in range(self.whole, end) if s not in self.above]


@dataclass
class RepairResult:
    asked: int = 0          # distinct batches (and reports) asked for again
    missing: int = 0        # still not in the log at the end


RESTARTS_MAX = 3        # a logger that dies more often than this is not restarted again
JOIN_S = 2.0            # a restarted logger records a heartbeat well within this


class LoggerKeeper:
    """The run's lcm-logger, started again (appending) whenever it dies."""

    def __init__(self, url: str, path: Path, deadline_s: float,
                 say: Callable[[str], None] = print) -> None:
        self.url = url
        self.path = path
        self.say = say
        self._ends = time.monotonic() + deadline_s
        self.daemon: spawn.Daemon | None = spawn.start_logger(url, path, deadline_s=deadline_s)
        self.restarts = 0
        self.failure: str | None = None   # why the log could not be kept: no logger any more

    def check(self) -> None:
        """Restart the logger if it died; after RESTARTS_MAX restarts, give up (self.failure)."""
        if self.daemon is None or self.daemon.alive():
            return
        code = self.daemon.process.returncode
        if self.restarts >= RESTARTS_MAX:
            self.daemon = None
            self.failure = (f"the logger died {self.restarts + 1} times (last exit status {code}); "
                            f"nothing was recorded after that: {self.path} is incomplete")
            self.say(f"[bold red]{self.failure}[/]")
            return
        self.restarts += 1
        _cut_to_whole_events(self.path)
        size = self.path.stat().st_size if self.path.exists() else 0
        try:
            self.daemon = spawn.start_logger(self.url, self.path, append=True,
                                             deadline_s=max(1.0, self._ends - time.monotonic()))
            # It has joined the group when it records something (heartbeats come at 5 Hz).
            joined = time.monotonic() + JOIN_S
            while self.path.stat().st_size == size and self.daemon.alive() and time.monotonic() < joined:
                time.sleep(0.02)
        except spawn.SpawnError as error:
            self.daemon = None
            self.failure = f"the logger died (exit status {code}) and could not be restarted: {error}"
            self.say(f"[bold red]{self.failure}[/]")
            return
        self.say(f"[yellow]the logger died (exit status {code}): restarted it (appending to {self.path}); "
                 "the DPUs send again what it missed[/]")

    def stop(self) -> None:
        if self.daemon is not None:
            spawn.stop(self.daemon)


def _cut_to_whole_events(path: Path) -> None:
    """Drop a last event the dead logger wrote only in part, so the appended log reads on."""
    try:
        data = path.read_bytes()
    except OSError:
        return
    log = read_bytes(data, str(path))
    whole = int(log.data_offset[-1] + log.data_len[-1]) if len(log) else 0
    if whole < len(data):
        os.truncate(path, whole)


class LogRepair:
    """Follows `path` (written by lcm-logger) for run `run_id` and fills its holes."""

    def __init__(self, control: Control, path: Path, run_id: int, dpu_ids: list[int],
                 keeper: LoggerKeeper | None = None) -> None:
        self.control = control
        self.keeper = keeper
        self.path = path
        self.run_id = run_id
        self.batches = {d: SeenBatches() for d in dpu_ids}
        self.reported: set[int] = set()
        self.result = RepairResult()
        self._read_to = 0
        self._last_poll = 0.0
        self._asked_at: dict[tuple[int, int], float] = {}
        self._budget = ASK_FIRST
        self._last_round: list[tuple[int, int]] = []  # (dpu, seq), seq -1 for the report

    def poll(self) -> None:
        """During the run: keep a logger, fill the holes behind each DPU's newest logged batch."""
        if self.keeper is not None:
            self.keeper.check()
        if time.monotonic() - self._last_poll < POLL_EVERY_S:
            return
        self._last_poll = time.monotonic()
        self._scan()
        self._ask({d: b.missing(None) for d, b in self.batches.items()}, set())

    def finish(self, reports: dict[int, skelmsg.report_t], stuck_s: float, limit_s: float) -> RepairResult:
        """After the run: asks until the log holds everything each report_t says was
        published, and the reports; gives up after `stuck_s` without progress or `limit_s`."""
        start = progress = time.monotonic()
        fewest = None
        while True:
            time.sleep(ROUND_S)
            if self.keeper is not None:
                self.keeper.check()
            self._scan()
            holes = {d: self.batches[d].missing(r.timing_batches) for d, r in reports.items()
                     if d in self.batches}
            no_report = set(reports) - self.reported
            outstanding = sum(map(len, holes.values())) + len(no_report)
            now = time.monotonic()
            if fewest is None or outstanding < fewest:
                fewest, progress = outstanding, now
            no_logger = self.keeper is not None and self.keeper.failure is not None
            if not outstanding or no_logger or now - progress >= stuck_s or now - start >= limit_s:
                self.result.missing = outstanding
                return self.result
            self._ask(holes, no_report, again_after_s=ROUND_S)

    def _scan(self) -> None:
        """Read what the logger appended since the last scan (whole events only)."""
        try:
            with self.path.open("rb") as f:
                f.seek(self._read_to)
                data = f.read()
        except OSError:
            return
        log = read_bytes(data, str(self.path))
        if not len(log):
            return
        self._read_to += int(log.data_offset[-1] + log.data_len[-1])
        ok, heads = timing_heads(log)
        mine = ok & (heads["run_id"] == self.run_id)
        for d, s in zip(heads["dpu"][mine].tolist(), heads["batch_seq"][mine].tolist(), strict=True):
            if d in self.batches:
                self.batches[d].add(s)
        for _, msg in log.messages(REPORT_CHANNEL):
            try:
                report = skelmsg.report_t.decode(bytes(msg))
            except (ValueError, struct.error):
                continue  # counted by the analysis; here it is just not a report
            if report.run_id == self.run_id:
                self.reported.add(report.dpu)

    def _ask(self, holes: dict[int, list[int]], no_report: set[int], again_after_s: float = 1.0) -> None:
        """RESEND for up to a window of batches not asked for within `again_after_s`, one
        command per DPU and contiguous range; a missing report rides on the first."""
        now = time.monotonic()

        def due(key: tuple[int, int]) -> bool:
            return now - self._asked_at.get(key, -again_after_s) >= again_after_s

        if self._last_round:
            arrived = all(self.batches[d].has(s) if s >= 0 else d in self.reported
                          for d, s in self._last_round)
            self._budget = min(2 * self._budget, ASK_MAX) if arrived else max(self._budget // 2, ASK_MIN)
        self._last_round = []
        budget = self._budget
        for dpu in sorted(set(holes) | no_report):
            wanted = [s for s in holes.get(dpu, []) if due((dpu, s))][:budget]
            report = dpu in no_report and due((dpu, -1))
            for i, (first, last) in enumerate(seq_ranges(wanted) or ([(0, -1)] if report else [])):
                self.control.command(skelmsg.command_t.RESEND, dpu=dpu, repeats=1, run_id=self.run_id,
                                     batch_from=first, batch_to=last, with_report=int(report and i == 0))
            for key in [(dpu, s) for s in wanted] + ([(dpu, -1)] if report else []):
                self._asked_at[key] = now
                self._last_round.append(key)
            self.result.asked = len(self._asked_at)
            budget -= len(wanted)
            if budget <= 0:
                return


def seq_ranges(seqs: list[int]) -> list[tuple[int, int]]:
    """Sorted seqs as inclusive (first, last) runs: [1, 2, 3, 7] -> [(1, 3), (7, 7)]."""
    out: list[tuple[int, int]] = []
    for s in seqs:
        if out and s == out[-1][1] + 1:
            out[-1] = (out[-1][0], s)
        else:
            out.append((s, s))
    return out

