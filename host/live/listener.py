"""What the DPUs send on the record URL (link.record_url), decoded once and kept: the one
live listener.

`skel status`, `skel run` (through Control, which adds the sending) and `skel watch`
each hear the DPUs through a Listener: every DPU's latest heartbeat (and every daemon's,
by host and pid), the reports, the configs by generation, each run's START (how far a
run has come: progress()), and, of the run it follows,
its statuses and its timing batches in a RecordStore decoded batch by batch as they
come. From these it answers what a live view asks: which DPUs are lost (their
heartbeats stopped for LOST_AFTER_S: the one live timeout), the report of the records
heard so far, and the run's faults as they appear — found by the report's own code
(analysis/measure/report.build_report, so by analysis/measure/faults.py's definitions)
and worded by fault_line, so `skel run`, `skel watch` and `skel report` name the same
faults the same way.

A Listener does not own the LCM instance: whoever drains it calls handle(channel,
data), from any one thread; readers take `lock` (or call wait_for). A malformed or
foreign message is counted per channel and ignored, never a crash.
"""

from __future__ import annotations

import struct
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

import skelmsg
from skeleton.analysis.measure.faults import (
    LOST_AFTER_S,
    Fault,
    jam_faults,
    lockout_faults,
    lockouts_from_status,
)
from skeleton.analysis.measure.report import RunReport, build_report
from skeleton.analysis.read.records import IMPOSSIBLE, RunRecords
from skeleton.analysis.read.seal import Verdict, Verifier
from skeleton.analysis.views.summary import fault_line
from skelmsg import contract
from skelmsg.contract import (
    CLOCK_CHANNEL,
    COMMAND_CHANNEL,
    CONFIG_CHANNEL,
    KEY_ENV,
    REPORT_CHANNEL,
    SEAL_FRESH_S,
    STATUS_CHANNEL,
    TIMING_CHANNEL,
)

from ..model import from_config
from .recordstore import KEEP_RECORDS, RecordStore

KEY_PROBLEMS = {  # what a refused status says about its DPU's key
    Verdict.SIGNED: "it signs its messages: it has a key and this host none (--key FILE or $" + KEY_ENV + ")",
    Verdict.UNSIGNED: "its messages are unsigned: it has no key and this host has one (give both the "
                      "same key, or neither)",
    Verdict.FORGED: "its messages fail the MAC: it has another key than this host's",
}
# Every channel a live view subscribes to (clock estimates: kept for `skel watch --once`'s final analysis).
CHANNELS = (CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL, REPORT_CHANNEL, CLOCK_CHANNEL)
STATE_NAMES = {
    skelmsg.status_t.STATE_UNCONFIGURED: "unconfigured",
    skelmsg.status_t.STATE_READY: "ready",
    skelmsg.status_t.STATE_ARMED: "armed",
    skelmsg.status_t.STATE_RUNNING: "running",
}
HEARTBEAT_S = contract.STATUS_PERIOD_MS / 1000  # a DPU heartbeats at 5 Hz (lost: faults.LOST_AFTER_S)
# `skel status`/`skel clock` listen until no DPU not heard before has been heard for this
# long (five heartbeats: a DPU that is up is heard even when a beat or two are lost).
QUIET_S = 5 * HEARTBEAT_S
# Configs kept (newest generations) so a running follower can re-send the one committed mid-run.
CONFIGS_KEPT = 4
# What anyone on the group may send is bounded before the host tool keeps or uses it: a stray
# generation of 2**63-1 once made every later push overflow int64. The host's own generations
# count pushes and its run ids are milliseconds since 1970: both far inside these ranges
# (integers a JSON reader or a double holds exactly).
GENERATION_MAX = 2**53 - 1
RUN_ID_MAX = 2**53 - 1
REPORTS_KEPT = 1024          # report_t kept, newest first out: a flood of them cannot grow memory
PROCESSES_KEPT = 4096        # daemons (host, pid) remembered for `skel status`, likewise
STATUSES_BEFORE_RUN = 1024   # statuses kept before a run is followed (its lockouts may come first)
STARTS_KEPT = 64             # the runs whose START was heard, newest kept
# A followed run's statuses are kept from this long before its oldest record held on
# (a heartbeat's gap before a record is what says a DPU was lost).
STATUSES_KEEP_NS = 10 * 10**9
# The faults of the records heard are found by the report's code over those the store holds
# (the newest: recordstore.py): it runs again once this many times its last cost has passed,
# so it takes a bounded share of a core; a new lockout in a heartbeat makes it run at once.
FAULTS_COST_FACTOR = 5.0
T = TypeVar("T")
_TIMING_FP = skelmsg.timing_t._get_packed_fingerprint()
_TIMING_HEAD = struct.Struct(">hqq")  # dpu, run_id, generation after the fingerprint


def is_generation(value: int) -> bool:
    """A generation the host tool may have made (not a stray message's)."""
    return 0 <= value <= GENERATION_MAX


def is_run_id(value: int) -> bool:
    return 0 < value <= RUN_ID_MAX


@dataclass
class DpuView:
    """The latest heartbeat of one DPU, and when it came."""

    status: skelmsg.status_t
    heard_mono: float

    @property
    def state(self) -> str:
        return STATE_NAMES.get(self.status.state, f"state {self.status.state}")


def fault_key(fault: Fault) -> tuple[Any, ...]:
    """What makes a fault the same one as it grows (an overrun's count, a stall's length).
    A lockout (once per process per run) and a jam (its chain) are the same whatever their
    at_s: it counts from the first release heard, which a batch resent late may move."""
    at_s = None if fault.kind in ("lockout", "jam") else fault.at_s
    return (fault.kind, fault.process, fault.dpu, tuple(fault.chain), fault.host, at_s, fault.count is None)


class Listener:
    """See the module comment. `follow(run_id)` keeps that run's statuses and timing;
    with `auto_follow` the first run whose timing is heard is followed, and a newer one
    replaces it unless `stay` (a live view that follows one run)."""

    def __init__(self, auto_follow: bool = False, stay: bool = False, key: bytes | None = None,
                 fresh_s: float | None = SEAL_FRESH_S) -> None:
        self.auto_follow = auto_follow
        self.stay = stay
        # Signed control (analysis/read/seal.py): with a key only genuine messages are heard;
        # without one, a sealed message is heard but says the sender has a key. A passive view
        # of a replayed log (`skel watch`) passes fresh_s=None: old seals are not replays there.
        self.key = key
        self._verifier = Verifier(key, fresh_s)
        self.refused: dict[str, int] = {}    # verdict -> messages the key check refused
        self.key_problems: dict[int, str] = {}  # DPU -> why it and this host disagree on the key
        self.lock = threading.Lock()
        self.changed = threading.Condition(self.lock)
        self.dpus: dict[int, DpuView] = {}
        # Every daemon heard, by (host, pid): DPUs started with --id auto all heartbeat as
        # DPU -1 until a config names them, and two daemons may claim one id.
        self.processes: dict[tuple[str, int], DpuView] = {}
        self._new_process_mono = time.monotonic()   # when the last daemon not heard before was
        self.reports: dict[tuple[int, int], skelmsg.report_t] = {}
        # Every config heard on the wire (ours and other `skel push`es'), newest generations only.
        self.configs: dict[int, skelmsg.config_t] = {}
        self._config_bytes: dict[int, bytes] = {}
        self.malformed: dict[str, int] = {}   # channel -> messages refused (undecodable or implausible)
        # The followed run.
        self.store: RecordStore | None = None
        self.keep_records = KEEP_RECORDS     # what its store holds at least (recordstore.py)
        self._statuses_trimmed_at = 0
        self.statuses: list[Any] = []        # of the followed run (before one is: the latest few)
        self.pending: list[bytes] = []       # its timing batches not decoded yet
        self.generations: set[int] = set()   # of its timing batches, from their headers
        self.next_run: int | None = None     # a newer run's timing was heard
        self.started = time.monotonic()      # when the followed run was first heard
        self.last_timing = 0.0
        self.last_report = 0.0
        self.faults: list[tuple[float, str]] = []   # (s since the run was first heard, fault_line)
        self.found: list[Fault] = []   # the same faults, whole (the console draws them on the graph)
        self._announced: set[tuple[Any, ...]] = set()
        # The followed run's lockouts heard in heartbeats, (DPU, process, cycle): each heartbeat
        # repeats its DPU's, so they are counted once each.
        self._lockouts: set[tuple[int, int, int]] = set()
        self._locks_seen = 0
        # heard_lockouts' last answer, and what it was for: (run, lockouts heard, generation)
        self._heard: tuple[tuple[Any, ...], list[Fault]] = ((), [])
        self._faults_due = 0.0
        # Each run's START, heard on the record URL (the sender sends its commands there too, and a
        # log replays them): run -> (cycle 0's release, its planned length; 0: until STOP), UTC ns.
        self.starts: dict[int, tuple[int, int]] = {}
        self._running_utc_ns = 0  # the DPUs' clock in the followed run's newest RUNNING heartbeat
        self._handlers: dict[str, Callable[[bytes, int], None]] = {
            STATUS_CHANNEL: self._status, REPORT_CHANNEL: self._report, CONFIG_CHANNEL: self._config,
            TIMING_CHANNEL: self._timing, COMMAND_CHANNEL: self._command}

    # --- hearing ----------------------------------------------------------------------
    @property
    def run_id(self) -> int | None:
        return None if self.store is None else self.store.run_id

    @property
    def rejected_messages(self) -> int:
        return sum(self.malformed.values())

    @property
    def latest(self) -> dict[int, Any]:
        """DPU -> its last status_t."""
        return {d: v.status for d, v in self.dpus.items()}

    def handle(self, channel: str, data: bytes) -> None:
        # t4 of a ping: first thing, before decoding, so only the wire and LCM are in the round trip.
        heard_ns = time.monotonic_ns()
        handler = self._handlers.get(channel)
        if handler is None:
            return
        verdict, message, _ = self._verifier.check(channel, data)
        if verdict is not Verdict.GENUINE:
            self._key_check_failed(channel, verdict, bytes(message))
            if verdict is not Verdict.SIGNED:
                return
        handler(bytes(message), heard_ns)

    def _key_check_failed(self, channel: str, verdict: Verdict, message: bytes) -> None:
        """Count it, and when a DPU's status says who sent it, say why that DPU and this host
        disagree (once per DPU: the first reason stands)."""
        with self.lock:
            self.refused[verdict.value] = self.refused.get(verdict.value, 0) + 1
        if channel != STATUS_CHANNEL:
            return
        try:
            dpu = skelmsg.status_t.decode(message).dpu
        except Exception:  # a foreign message: counted above, nothing to name
            return
        why = KEY_PROBLEMS.get(verdict)
        if why is not None:
            with self.lock:
                self.key_problems.setdefault(dpu, why)

    def key_lines(self) -> list[str]:
        """One line per DPU whose key disagrees with this host's, and one for anything else refused."""
        with self.lock:
            lines = [f"DPU {d if d >= 0 else '(auto)'}: {why}"
                     for d, why in sorted(self.key_problems.items())]
            others = {v: n for v, n in self.refused.items() if v != Verdict.SIGNED.value}
        if others and not lines:
            lines.append("messages refused by the key check: "
                         + ", ".join(f"{n} {v}" for v, n in sorted(others.items())))
        return lines

    def _refuse(self, channel: str) -> None:
        with self.lock:
            self.malformed[channel] = self.malformed.get(channel, 0) + 1

    def _decode(self, channel: str, cls: type, data: bytes) -> Any:
        """Decode, or count a malformed/foreign message and return None: never crash."""
        try:
            return cls.decode(data)
        except Exception:  # whatever a foreign message makes the generated decoder raise
            self._refuse(channel)
            return None

    def _status(self, data: bytes, heard_ns: int) -> None:
        status = self._decode(STATUS_CHANNEL, skelmsg.status_t, data)
        if status is None:
            return
        if not (status.dpu == -1 or status.dpu > 0):  # ids are 1..32767, -1 before --id auto found its own
            self._refuse(STATUS_CHANNEL)
            return
        now = time.monotonic()
        with self.changed:
            view = DpuView(status, now)
            self.dpus[status.dpu] = view
            key = (status.host, status.pid)
            if key not in self.processes:
                self._new_process_mono = now
                if len(self.processes) >= PROCESSES_KEPT:
                    del self.processes[next(iter(self.processes))]
            self.processes[key] = view
            if self.store is None or status.run_id == self.store.run_id:
                self.statuses.append(status)
                if self.store is None:
                    del self.statuses[:-STATUSES_BEFORE_RUN]
                else:
                    self._lockouts.update((status.dpu, lock.process, lock.cycle) for lock in status.lockouts)
                    if status.state == skelmsg.status_t.STATE_RUNNING:
                        self._running_utc_ns = max(self._running_utc_ns, status.utc_ns)
            self.status_heard(status, heard_ns)
            self.changed.notify_all()

    def status_heard(self, status: skelmsg.status_t, heard_ns: int) -> None:
        """Called with the lock held for every plausible heartbeat (Control matches pings)."""

    def _report(self, data: bytes, _heard_ns: int) -> None:
        report = self._decode(REPORT_CHANNEL, skelmsg.report_t, data)
        if report is None:
            return
        if report.dpu <= 0 or not is_run_id(report.run_id):
            self._refuse(REPORT_CHANNEL)
            return
        with self.changed:
            self.reports.pop((report.dpu, report.run_id), None)
            self.reports[(report.dpu, report.run_id)] = report
            while len(self.reports) > REPORTS_KEPT:
                del self.reports[next(iter(self.reports))]
            if report.run_id == self.run_id:
                self.last_report = time.monotonic()
            self.changed.notify_all()

    def _config(self, data: bytes, _heard_ns: int) -> None:
        if len(data) >= 16 and self._config_bytes.get(int.from_bytes(data[8:16], "big", signed=True)) == data:
            return  # the once-a-second re-send of a config already decoded (generation after the fingerprint)
        config = self._decode(CONFIG_CHANNEL, skelmsg.config_t, data)
        if config is None:
            return
        if not is_generation(config.generation):  # not one of ours, and it would crowd ours out
            self._refuse(CONFIG_CHANNEL)
            return
        with self.changed:
            self.configs[config.generation] = config
            self._config_bytes[config.generation] = data
            for old in sorted(self.configs)[:-CONFIGS_KEPT]:
                del self.configs[old]
                self._config_bytes.pop(old, None)
            self.changed.notify_all()

    def _command(self, data: bytes, _heard_ns: int) -> None:
        """A run's START: when its cycle 0 is released and for how long (progress())."""
        command = self._decode(COMMAND_CHANNEL, skelmsg.command_t, data)
        if command is None or command.kind != skelmsg.command_t.START:
            return
        if not is_run_id(command.run_id) or command.duration_ns < 0:
            self._refuse(COMMAND_CHANNEL)
            return
        with self.lock:
            self.starts.pop(command.run_id, None)
            self.starts[command.run_id] = (command.at_utc_ns, command.duration_ns)
            while len(self.starts) > STARTS_KEPT:
                del self.starts[next(iter(self.starts))]

    def _timing(self, data: bytes, _heard_ns: int) -> None:
        if len(data) < 8 + _TIMING_HEAD.size or data[:8] != _TIMING_FP:
            self._refuse(TIMING_CHANNEL)
            return
        _, run_id, generation = _TIMING_HEAD.unpack_from(data, 8)
        with self.lock:
            if self.store is None or run_id != self.store.run_id:
                if not self.auto_follow:
                    return
                if self.store is not None:
                    self.next_run = run_id
                    if self.stay:
                        return
                self._follow(run_id)
            self.generations.add(generation)
            self.pending.append(data)
            self.last_timing = time.monotonic()

    # --- the followed run -------------------------------------------------------------
    def follow(self, run_id: int) -> None:
        """Keep the statuses and timing of run `run_id` from now on."""
        with self.lock:
            self._follow(run_id)

    def _follow(self, run_id: int) -> None:
        self.store = RecordStore(run_id, self.keep_records)
        self._statuses_trimmed_at = 0  # the store's `first` when the statuses were last trimmed
        self.pending, self.faults, self.found, self.next_run = [], [], [], None
        self.generations = set()
        self.statuses = [s for s in self.statuses if s.run_id == run_id]
        self._lockouts = {(s.dpu, lock.process, lock.cycle) for s in self.statuses for lock in s.lockouts}
        self._announced, self._locks_seen, self._faults_due = set(), 0, 0.0
        running = [s.utc_ns for s in self.statuses if s.state == skelmsg.status_t.STATE_RUNNING]
        self._running_utc_ns = max(running, default=0)
        self.started = time.monotonic()
        self.last_report = 0.0

    def progress(self) -> tuple[float, float | None] | None:
        """How far the followed run has come: seconds since its cycle 0 was released, by its
        DPUs' clocks in their newest heartbeat while running (a run stopped early stays where it
        stopped), and its planned length in seconds (None: until STOP); None before its START
        and a heartbeat of it running were heard."""
        with self.lock:
            start = None if self.store is None else self.starts.get(self.store.run_id)
            now_ns = self._running_utc_ns
        if start is None or now_ns == 0:
            return None
        at_ns, duration_ns = start
        elapsed_ns = max(0, now_ns - at_ns)
        if duration_ns:
            elapsed_ns = min(elapsed_ns, duration_ns)
        return elapsed_ns / 1e9, duration_ns / 1e9 if duration_ns else None

    def absorb(self) -> None:
        """Decode the timing batches that came since the last call (cheap: those only)."""
        with self.lock:
            pending, self.pending = self.pending, []
            store = self.store
        if store is not None:
            store.add(pending)

    def report(self) -> RunReport | None:
        """The report of the followed run over what was heard so far, by `skel report`'s
        code (None before a run, its records and its config)."""
        self.absorb()
        return self.report_of(self.run_records())

    def run_records(self) -> RunRecords | None:
        """The followed run's records decoded so far (absorb decodes the newest), and the
        batches lost by the DPUs' own counts when their reports came."""
        with self.lock:
            store = self.store
            reports = [r for (_, run_id), r in self.reports.items() if run_id == self.run_id]
        return None if store is None else store.run({r.dpu: r.timing_batches for r in reports})

    def report_of(self, run: RunRecords | None) -> RunReport | None:
        """The report of `run` (a run_records() of the followed run), by `skel report`'s code."""
        with self.lock:
            statuses, configs = list(self.statuses), dict(self.configs)
            reports = [r for (_, run_id), r in self.reports.items() if run_id == self.run_id]
        if run is None or len(run.records) == 0:
            return None
        config = configs.get(max(run.generations))
        if config is None:
            return None
        report = build_report(config, run, statuses, reports, None, self.skipped(run), configs)
        store = self.store
        if store is not None and store.run_id == run.run_id:
            store.searched = max(store.searched, run.first + len(run.records))
            self.forget()
        return report

    def forget(self) -> None:
        """Let the followed run's store forget the records its readers are done with
        (recordstore.py), and the statuses heard before its oldest record held, but the first
        to name each lockout (the report's lockouts come from those): a long run stays bounded."""
        store = self.store
        if store is None:
            return
        store.forget()
        # (also after the store forgot on its own, its readers too far behind: RecordStore.add)
        if store.first == self._statuses_trimmed_at or store.held_from_ns is None:
            return
        self._statuses_trimmed_at = store.first
        since = store.held_from_ns - STATUSES_KEEP_NS
        with self.lock:
            named: set[tuple[int, int]] = set()
            kept = []
            for status in self.statuses:
                names = {(status.dpu, lock.process) for lock in status.lockouts} - named
                named |= names
                if names or status.utc_ns >= since:
                    kept.append(status)
            self.statuses = kept

    def skipped(self, run: RunRecords) -> dict[str, int]:
        """What was skipped as malformed (by channel, and `run`'s records with impossible
        times), under the keys `skel report` counts them by; none of the channels with none."""
        with self.lock:
            malformed = dict(self.malformed)
        malformed[TIMING_CHANNEL] = malformed.get(TIMING_CHANNEL, 0) + run.malformed
        malformed[IMPOSSIBLE] = run.impossible
        return {channel: n for channel, n in sorted(malformed.items()) if n}

    def lost(self, ids: Iterable[int]) -> list[int]:
        """DPUs among `ids` not heard for LOST_AFTER_S (or never)."""
        now = time.monotonic()
        with self.lock:
            return [i for i in ids if i not in self.dpus or now - self.dpus[i].heard_mono > LOST_AFTER_S]

    def new_faults(self, running: bool) -> list[Fault]:
        """The followed run's faults not returned before, in the order found: those of the
        report over the records heard so far (re-computed as FAULTS_COST_FACTOR allows, at
        once when a heartbeat names a new lockout) and, while `running`, the DPUs of its
        config whose heartbeats stopped (LOST_AFTER_S). Once the run is over (`running`
        false) the report's own dpu_lost counts instead."""
        report = self.timed_search(self.report) if self.faults_due() or not running else None
        return self.announce(report, running, self.heard_lockouts() if report is None else [])

    def heard_lockouts(self) -> list[Fault]:
        """The lockouts (and jams) the followed run's heartbeats name, as the report would:
        a report needs timing records, and a cycle computing past its lockout instant has
        none until it ends (a DPU that named it at 100 ms stopped on it at 0.56 s, when its
        300 ms cycle's record came). When its window passed is the records' to say."""
        config = self.newest_config()
        with self.lock:
            # the statuses are read only when one named a lockout not read before
            key = (self.run_id, len(self._lockouts), None if config is None else config.generation)
            if not self._lockouts or key == self._heard[0]:
                return list(self._heard[1]) if self._lockouts else []
            statuses, run_id = list(self.statuses), self.run_id
        if config is None or run_id is None:
            return []
        locks = lockouts_from_status(statuses, run_id)
        system = from_config(config)
        found = lockout_faults(locks, system) + jam_faults(locks, system)
        with self.lock:
            self._heard = (key, found)
        return list(found)

    def faults_due(self) -> bool:
        """Whether to search the records for faults again: FAULTS_COST_FACTOR times the last
        search's cost has passed, or a heartbeat named a lockout not known then."""
        return time.monotonic() >= self._faults_due or self._lockouts_heard() > self._locks_seen

    def timed_search(self, search: Callable[[], T]) -> T:
        """search() (a report of the followed run's records), its cost and the lockouts heard
        before it noted for faults_due, unless a newer run was followed meanwhile."""
        with self.lock:
            run_id, locks = self.run_id, len(self._lockouts)
        started = time.monotonic()
        try:
            return search()
        finally:
            with self.lock:
                if self.run_id == run_id:
                    self._faults_due = time.monotonic() + FAULTS_COST_FACTOR * (time.monotonic() - started)
                    self._locks_seen = locks

    def _lockouts_heard(self) -> int:
        with self.lock:
            return len(self._lockouts)

    def announce(self, report: RunReport | None, running: bool, heard: Sequence[Fault] = ()) -> list[Fault]:
        """The faults of `report` (a report of the followed run's records: one of a run
        followed before, which a search begun earlier may hand in, is dropped), those `heard`
        in heartbeats, and the DPUs lost meanwhile that were not returned before; each is also
        listed in `faults`."""
        now = time.monotonic()
        found = [] if report is None else [f for f in report.faults if f.kind != "dpu_lost" or not running]
        found += heard
        config = self.newest_config()
        if running and config is not None:
            lost = self.lost(sorted({int(p.dpu) for p in config.processes}))
            views = self.snapshot()
            found += [Fault(kind="dpu_lost", dpu=d, detail=f"not heard for {now - views[d].heard_mono:.2f} s"
                            if d in views else "never heard") for d in lost]
        new = []
        with self.lock:  # a live view announces from two threads (watch._FaultFinder)
            if report is not None and report.run_id != self.run_id:
                return new
            for fault in found:
                key = fault_key(fault)
                if key not in self._announced:
                    self._announced.add(key)
                    new.append(fault)
                    self.faults.append((time.monotonic() - self.started, fault_line(fault)))
                    self.found.append(fault)
        return new

    # --- waiting ----------------------------------------------------------------------
    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until predicate() (evaluated under the lock) holds, or time out."""
        deadline = time.monotonic() + timeout_s
        with self.changed:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self.changed.wait(min(left, 0.1))
        return True

    def snapshot(self) -> dict[int, DpuView]:
        with self.lock:
            return dict(self.dpus)

    def listen(self, limit_s: float, quiet_s: float = QUIET_S) -> float:
        """Listen until no daemon not heard before has been heard for `quiet_s` (from the
        start, or from the last new one), or `limit_s` in all; the seconds listened."""
        start = time.monotonic()
        self.wait_for(lambda: time.monotonic() - max(start, self._new_process_mono) >= quiet_s, limit_s)
        return time.monotonic() - start

    def daemons(self) -> list[DpuView]:
        """The latest heartbeat of every daemon heard, by DPU id, then host and pid."""
        with self.lock:
            views = list(self.processes.values())
        return sorted(views, key=lambda v: (v.status.dpu, v.status.host, v.status.pid))

    def newest_config(self) -> skelmsg.config_t | None:
        """The config of the followed run's newest generation; before its first timing batch,
        the newest config heard."""
        with self.lock:
            return self.configs.get(max(self.generations, default=max(self.configs, default=-1)))

    def config_of(self, generation: int) -> skelmsg.config_t | None:
        """The config of `generation` if it was heard on the wire (pushed by any host)."""
        with self.lock:
            return self.configs.get(generation)
