"""`skel watch`: a live view of a run (or of lcm-logplayer replaying one): what a
Listener hears (listener.py), its tables kept up to date as the records arrive
(analysis/measure/tally.py: each refresh costs the new records only, by `skel report`'s
definitions) and its faults found by `skel report`'s whole analysis (report.build_report
over the records heard so far) in a thread of their own, as often as that allows.

The view subscribes to config, status, timing, report and clock (queues unlimited: a
timing batch must never be dropped by LCM) and redraws every REFRESH_S. `--once`
follows one run without a display and, when it ends, prints the final tables by
running `skel report`'s analysis over an in-memory log of what it heard, so both
print the same tables for the same messages.
"""

from __future__ import annotations

import json
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any

from rich.live import Live

from skeleton.analysis.errors import (
    EXIT_BAD_INPUT,
    EXIT_FAILED,
    EXIT_FATAL_FLAW,
    EXIT_INTERRUPTED,
    EXIT_OK,
)
from skeleton.analysis.measure.report import RunReport
from skeleton.analysis.measure.run import analyze_log
from skeleton.analysis.measure.tally import GenerationTally, RunTally
from skeleton.analysis.read.logreader import encode_events, read_bytes
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.views.console import OutputConsole, reader_closed
from skeleton.analysis.views.summary import print_summary
from skeleton.analysis.views.tables import print_report
from skelmsg.contract import COMMAND_CHANNEL

from ..live import spawn
from ..live.control import subscribe
from ..live.listener import CHANNELS, LOST_AFTER_S, Listener
from ..live.recordstore import RecordStore
from ..sysfile.link import record_listen_url, record_url, rmem_max
from ..theory.predictor import predictor
from .watch_view import render

REFRESH_S = 0.4  # redraw period: at least twice a second
QUIET_S = 2.0  # no timing for this long after data stopped: the run ended
REPORT_GRACE_S = 0.5  # after the last report_t, for the messages logged behind it


class Heard:
    """What `skel watch` heard: a Listener following the newest run (with `keep_events`,
    --once, its first run only, and every message kept for the final analysis)."""

    def __init__(self, keep_events: bool, key: bytes | None = None) -> None:
        # A passive view, also of lcm-logplayer replaying a signed run: no freshness window.
        self.listener = Listener(auto_follow=True, stay=keep_events, key=key, fresh_s=None)
        self.key = key
        self.keep_events = keep_events
        self.events: list[tuple[int, str, bytes]] = []
        self._tally: RunTally | None = None
        self.tables: GenerationTally | None = None  # of the followed run, the last refresh's
        self.lost_batches = 0  # timing batches of the followed run lost so far
        self.skipped: dict[str, int] = {}  # what was skipped as malformed (Listener.skipped)
        self._covered: tuple[int | None, int] = (None, 0)  # (run, records) the last search for faults covered

    @property
    def run_id(self) -> int | None:
        return self.listener.run_id

    @property
    def store(self) -> RecordStore | None:
        return self.listener.store

    @property
    def latest(self) -> dict[int, Any]:
        return self.listener.latest

    @property
    def faults(self) -> list[tuple[float, str]]:
        return self.listener.faults

    def handle(self, channel: str, data: bytes) -> None:
        if self.keep_events:
            self.events.append((time.time_ns() // 1000, channel, data))
        self.listener.handle(channel, data)

    def ended(self) -> bool:
        """Every DPU of the run sent its report_t (and the grace passed), or the timing
        stopped for QUIET_S, or a newer run began."""
        heard = self.listener
        if heard.store is None:
            return False
        now = time.monotonic()
        if heard.next_run is not None or (heard.last_timing and now - heard.last_timing > QUIET_S):
            return True
        config = heard.config_of(max(heard.generations, default=-1))
        reported = {d for (d, run_id) in heard.reports if run_id == heard.run_id}
        everyone = bool(config and reported >= {d.id for d in config.dpus})
        return everyone and now - heard.last_report > REPORT_GRACE_S

    def refresh(self) -> GenerationTally | None:
        """Decode the batches heard since the last refresh and tally their records: the
        tables of the run's newest generation (None before a run, its records and its config)."""
        self.listener.absorb()
        run = self.listener.run_records()
        if run is None:
            return None
        if self._tally is None or self._tally.run_id != run.run_id:  # a new run: none of the old tables
            self._tally, self.tables, self.lost_batches = RunTally(run.run_id), None, 0
        self.skipped = self.listener.skipped(run)
        if len(run.records):
            with self.listener.lock:
                configs = dict(self.listener.configs)
            self.tables = self._tally.update(run, configs) or self.tables
            self.lost_batches = sum(b["to_seq"] - b["from_seq"] + 1 for b in run.lost_batches)
        store = self.listener.store
        if store is not None and store.run_id == run.run_id:
            store.tallied = self._tally.seen
            self.listener.forget()
        # DPUs lost and lockouts heartbeats name: at once, not at the next search
        self.listener.announce(None, self._running(), self.listener.heard_lockouts())
        return self.tables

    def pinned_here(self) -> set[int]:
        """The CPUs this machine's DPUs of the followed run are pinned to (Listener.newest_config)."""
        config = self.listener.newest_config()
        if config is None:
            return set()
        return {int(d.cpu) for d in config.dpus if d.cpu >= 0 and spawn.is_local(d.host)}

    def find_faults(self) -> RunReport | None:
        """The report of the records decoded so far (None before a run and its config); the
        faults it finds are listed (`faults`) as they appear. Safe beside refresh()."""
        run = self.listener.run_records()
        report = self.listener.report_of(run)
        if report is None or run is None:
            return None
        self._covered = (run.run_id, run.first + len(run.records))
        self.listener.announce(report, running=self._running())
        return report

    @property
    def covered(self) -> int:
        """The followed run's records the last search for faults covered."""
        run_id, records = self._covered
        return records if run_id == self.run_id else 0

    def _running(self) -> bool:
        """A DPU is lost while the others' timing still flows; when the whole run stopped
        (or the replay ended), nobody is."""
        return time.monotonic() - self.listener.last_timing <= LOST_AFTER_S and not self.ended()

    def final(self) -> tuple[RunReport, str | None]:
        """`skel report`'s analysis over an in-memory log of everything heard, its prediction
        beside it (a `samples:` file is looked for here), and why there is none."""
        run = analyze_log(read_bytes(encode_events(self.events), "<heard>"), self.run_id, self.key)
        missing = run.add_prediction(predictor(Path("system.yaml")))
        return run.report, missing


def _subscribe(url: str, heard: Heard) -> Any:
    """Heard hears the record URL of the control URL `url`: what a run records (host/sysfile/link.py)."""
    import lcm

    record = record_url(url)
    lc = lcm.LCM(record_listen_url(url, rmem_max()))
    # The commands too: the live view reads none, but --once's final analysis is `skel report`'s
    # of everything heard, and a run's START and the STOP that cut it short say it was (stopped.py).
    subscribe(lc, record, (*CHANNELS, COMMAND_CHANNEL), heard.handle)
    return lc


def _pump(lc: Any, until: float) -> None:
    """Handle messages until the monotonic instant `until`."""
    failures = 0
    while (left := until - time.monotonic()) > 0:
        try:
            lc.handle_timeout(max(1, int(left * 1000)))
            failures = 0
        except OSError:
            # A signal cut the wait short (EINTR; LCM calls it an error): its handler runs at
            # this loop's next turn, SIGINT and SIGTERM raising KeyboardInterrupt. A real
            # failure repeats.
            failures += 1
            if failures > 3:
                raise


def watch_command(url: str, once: bool, duration_s: float | None, as_json: bool = False,
                  key: bytes | None = None, all_tables: bool = False) -> int:
    """`skel watch [--url URL] [--once [--all | --json]] [--duration S]`: 0; 3 (--once) on a lockout or jam;
    1 when --once heard no run; 2 on a bad URL; 130 when ended by Ctrl-C or SIGTERM."""
    heard = Heard(keep_events=once, key=key)
    try:
        lc = _subscribe(url, heard)
    except (RuntimeError, ValueError) as e:  # lcm's, or record_url's; a taken port is ControlError
        print(f"skel watch: cannot open LCM URL {url}: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        if once:
            return _once(lc, heard, url, deadline, as_json, all_tables)
        _live(lc, heard, url, deadline)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    return EXIT_OK


def _live(lc: Any, heard: Heard, url: str, deadline: float | None) -> None:
    console = OutputConsole()
    allowed = os.sched_getaffinity(0)
    finder = _FaultFinder(heard)
    with Live(render(heard, url), console=console, auto_refresh=False, transient=False) as live:
        try:
            # A view nobody reads any more (`skel watch | head`, the reader gone before the view's
            # only drawing at the end) has nothing left to do: watching changes no run.
            while (deadline is None or time.monotonic() < deadline) and not reader_closed():
                tick = time.monotonic() + REFRESH_S
                _pump(lc, tick if deadline is None else min(tick, deadline))
                heard.refresh()
                # Every thread (the search for faults, its pools, numpy's): a run that pins DPUs here,
                # or the next one; each refresh, as threads come and go.
                spawn.keep_off(heard.pinned_here(), allowed, spawn.own_threads())
                finder.check()
                live.update(render(heard, url), refresh=True)
        finally:
            finder.stop()


class _FaultFinder:
    """Looks for the run's faults with `skel report`'s whole analysis, again and again, in a
    thread of its own: at 10^6 records one search takes seconds, which the tables (tallied
    at every refresh) must not wait for. Like `skel run`'s, a search waits FAULTS_COST_FACTOR
    times the last one's cost (the DPUs on this machine need the CPU more) unless a
    heartbeat names a lockout not known at the last one. The view says how many records
    the last one covered. An error in a search stops the thread and is raised by check()."""

    def __init__(self, heard: Heard) -> None:
        self.heard = heard
        self.error: BaseException | None = None
        self._stopped = threading.Event()
        self._thread = threading.Thread(target=self._loop, name="skel-watch-faults", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        listener = self.heard.listener
        try:
            while not self._stopped.wait(REFRESH_S):
                if listener.faults_due():
                    listener.timed_search(self.heard.find_faults)
        except BaseException as e:  # handed to the main thread, raised there
            self.error = e

    def check(self) -> None:
        if self.error is not None:
            raise self.error

    def stop(self, wait_s: float = 0.0) -> None:
        """Stop searching; wait up to `wait_s` for a search under way to end."""
        self._stopped.set()
        self._thread.join(wait_s)


def _once(lc: Any, heard: Heard, url: str, deadline: float | None, as_json: bool, all_tables: bool) -> int:
    # Subscribed: say so, so a script may start a replay now without losing its first messages.
    print(f"skel watch: waiting for a run on {url} (hearing its record URL {record_url(url)})",
          file=sys.stderr, flush=True)
    announced = None
    while not heard.ended() and (deadline is None or time.monotonic() < deadline):
        tick = time.monotonic() + REFRESH_S
        _pump(lc, tick if deadline is None else min(tick, deadline))
        if heard.run_id is not None and heard.run_id != announced:
            announced = heard.run_id
            print(f"skel watch: following run {announced} on {url}", file=sys.stderr)
    if heard.run_id is None:
        print(f"skel watch: no run heard on {url}", file=sys.stderr)
        return EXIT_FAILED
    try:
        report, missing = heard.final()
    except LogError as e:
        print(f"skel watch: run {heard.run_id}: {e}", file=sys.stderr)
        return EXIT_FAILED
    if missing:
        print(f"skel watch: run {heard.run_id}: {missing}", file=sys.stderr)
    if as_json:
        print(json.dumps(report.to_json(), indent=2))
    elif all_tables:
        print_report(report)
    else:
        print_summary(report)   # one screen, as `skel run` and `skel report` print it
    return EXIT_FATAL_FLAW if report.fatal else EXIT_OK
