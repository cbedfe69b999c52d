"""`skel watch`: a live view of a run (or of lcm-logplayer replaying one), computed by
the same code as `skel report` (report.build_report over the records heard so far).

The view subscribes to config, status, timing and report (queues unlimited: a
timing batch must never be dropped by LCM), decodes the timing batches that
arrived since the last refresh into arrays grown in chunks, and redraws twice a
second. `--once` follows one run without a display and, when it ends, prints the
final tables by running `skel report`'s analysis over an in-memory log of what it
heard, so both print the same tables for the same messages.
"""

from __future__ import annotations

import struct
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from rich.console import Console
from rich.live import Live

import skelmsg
from skelmsg.contract import CLOCK_CHANNEL, CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL

from ..exitcodes import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_FATAL_FLAW, EXIT_INTERRUPTED, EXIT_OK
from ..measure.report import RunReport, build_report
from ..measure.run import analyze_log
from ..read.coltable import ColumnTable
from ..read.messages import LogError
from ..read.records import INPUT_DTYPE, RECORD_DTYPE, RunRecords, decode_run, lost_batches
from .watch_view import render

# Clock-offset estimates too: the report corrects cross-host latencies with them.
CHANNELS = (CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL, REPORT_CHANNEL, CLOCK_CHANNEL)
REFRESH_S = 0.4  # redraw period: at least twice a second
QUIET_S = 2.0  # no timing for this long after data stopped: the run ended
REPORT_GRACE_S = 0.5  # after the last report_t, for the messages logged behind it
HEARTBEAT_LOST_S = 1.0  # status_t comes at >= 5 Hz: a DPU silent this long is lost
_TIMING_FP = skelmsg.timing_t._get_packed_fingerprint()
_CONFIG_FP = skelmsg.config_t._get_packed_fingerprint()
_TIMING_HEAD = struct.Struct(">hqq")  # dpu, run_id, generation after the fingerprint
_CONFIG_HEAD = struct.Struct(">q")  # generation


class RecordStore:
    """The timing records of one run, decoded batch by batch as they arrive, in numpy
    arrays grown in chunks (doubling), so a refresh costs the new batches only."""

    def __init__(self, run_id: int) -> None:
        self.run_id = run_id
        self.records = {name: np.empty(4096, dtype=RECORD_DTYPE[name]) for name in RECORD_DTYPE.names or ()}
        self.inputs = {name: np.empty(8192, dtype=INPUT_DTYPE[name]) for name in INPUT_DTYPE.names or ()}
        self.n_records = 0
        self.n_inputs = 0
        self.batch_keys: set[tuple[int, int]] = set()
        self.batch_dpu: list[int] = []
        self.batch_seq: list[int] = []
        self.generations: set[int] = set()
        self.malformed = 0
        self.duplicates = 0

    def add(self, messages: list[bytes]) -> None:
        if not messages:
            return
        chunk = decode_run(messages, self.run_id)
        self.malformed += chunk.malformed
        self.duplicates += chunk.duplicates
        rec = chunk.records
        keys = np.stack([rec["dpu"].astype(np.int64), rec["batch_seq"]], axis=1)
        fresh = np.ones(len(rec), dtype=bool)
        for dpu, seq in np.unique(keys, axis=0).tolist() if len(rec) else []:
            if (dpu, seq) in self.batch_keys:  # heard twice (re-sent or replayed twice)
                fresh &= ~((keys[:, 0] == dpu) & (keys[:, 1] == seq))
                self.duplicates += 1
            else:
                self.batch_keys.add((dpu, seq))
                self.batch_dpu.append(dpu)
                self.batch_seq.append(seq)
        renumber = np.cumsum(fresh) - 1 + self.n_records
        inputs = chunk.inputs[fresh[chunk.inputs["record"]]] if len(chunk.inputs) else chunk.inputs
        inputs = inputs.copy()
        inputs["record"] = renumber[inputs["record"]]
        self.records, self.n_records = _append(self.records, self.n_records, rec[fresh])
        self.inputs, self.n_inputs = _append(self.inputs, self.n_inputs, inputs)
        self.generations.update(np.unique(rec["generation"][fresh]).tolist())

    def run(self, expected_batches: dict[int, int] | None = None) -> RunRecords:
        return RunRecords(
            run_id=self.run_id,
            records=ColumnTable({k: v[: self.n_records] for k, v in self.records.items()}, RECORD_DTYPE),
            inputs=ColumnTable({k: v[: self.n_inputs] for k, v in self.inputs.items()}, INPUT_DTYPE),
            batches=len(self.batch_keys),
            generations=sorted(self.generations),
            lost_batches=lost_batches(
                np.asarray(self.batch_dpu, dtype=np.int64), np.asarray(self.batch_seq, dtype=np.int64),
                expected_batches,
            ),
            malformed=self.malformed,
            duplicates=self.duplicates,
        )


def _append(
    columns: dict[str, np.ndarray], used: int, rows: ColumnTable
) -> tuple[dict[str, np.ndarray], int]:
    """Append rows, doubling the capacity when full (amortised O(1) per row). Rows
    below `used` are never written again, so earlier snapshots (views) stay valid."""
    need = used + len(rows)
    out = {}
    for name, array in columns.items():
        if need > len(array):
            grown = np.empty(max(need, 2 * len(array)), dtype=array.dtype)
            grown[:used] = array[:used]
            array = grown
        array[used:need] = rows[name]
        out[name] = array
    return out, need


@dataclass
class Heard:
    """Everything heard on the control URL, and the run being followed."""

    keep_events: bool  # --once: keep every message for the final analysis
    events: list[tuple[int, str, bytes]] = field(default_factory=list)
    configs: dict[int, bytes] = field(default_factory=dict)  # generation -> last config_t heard
    decoded: dict[int, Any] = field(default_factory=dict)
    statuses: list[Any] = field(default_factory=list)  # of the followed run
    latest: dict[int, Any] = field(default_factory=dict)  # dpu -> its last status_t
    reports: list[Any] = field(default_factory=list)
    store: RecordStore | None = None
    pending: list[bytes] = field(default_factory=list)  # timing batches not decoded yet
    malformed: dict[str, int] = field(default_factory=dict)
    faults: list[tuple[float, str]] = field(default_factory=list)  # (seconds since start, text)
    announced: set[tuple[str, str]] = field(default_factory=set)
    started: float = field(default_factory=time.monotonic)  # when the followed run was first heard
    heartbeat: dict[int, float] = field(default_factory=dict)  # dpu -> when its last status_t came
    last_timing: float = 0.0
    last_report: float = 0.0
    next_run: int | None = None  # a newer run began while following one
    generations: set[int] = field(default_factory=set)  # of the followed run, from timing headers
    covered: int = 0  # records the last snapshot's tables cover

    @property
    def run_id(self) -> int | None:
        return None if self.store is None else self.store.run_id

    def handle(self, channel: str, data: bytes) -> None:
        if self.keep_events:
            self.events.append((time.time_ns() // 1000, channel, data))
        handlers: dict[str, Callable[[bytes], None]] = {
            TIMING_CHANNEL: self._timing, STATUS_CHANNEL: self._status,
            REPORT_CHANNEL: self._report, CONFIG_CHANNEL: self._config,
        }  # fmt: skip
        handler = handlers.get(channel)
        if handler is not None:
            handler(data)

    def _bad(self, channel: str) -> None:
        self.malformed[channel] = self.malformed.get(channel, 0) + 1

    def _timing(self, data: bytes) -> None:
        if len(data) < 8 + _TIMING_HEAD.size or data[:8] != _TIMING_FP:
            self._bad(TIMING_CHANNEL)
            return
        _, run_id, generation = _TIMING_HEAD.unpack_from(data, 8)
        if self.store is None:
            self._follow(run_id)
        elif run_id != self.store.run_id:
            self.next_run = run_id
            if self.keep_events:
                return  # --once: the followed run is over
            self._follow(run_id)
        self.generations.add(generation)
        if not self.keep_events:  # --once analyses the kept events instead
            self.pending.append(data)
        self.last_timing = time.monotonic()

    def _follow(self, run_id: int) -> None:
        self.store = RecordStore(run_id)
        self.pending, self.reports, self.faults, self.next_run = [], [], [], None
        self.generations = set()
        self.statuses = [s for s in self.statuses if s.run_id == run_id]
        self.announced.clear()
        self.started = time.monotonic()
        for status in self.statuses:  # heard before its first timing batch
            self._lockouts(status)
        self.last_report = 0.0

    def _decode(self, channel: str, data: bytes, decode: Callable[[bytes], Any]) -> Any:
        try:
            return decode(data)
        except Exception:  # a malformed message is counted, never fatal
            self._bad(channel)
            return None

    def _status(self, data: bytes) -> None:
        status = self._decode(STATUS_CHANNEL, data, skelmsg.status_t.decode)
        if status is None:
            return
        self.latest[status.dpu] = status
        self.heartbeat[status.dpu] = time.monotonic()
        if self.store is None or status.run_id == self.store.run_id:
            self.statuses.append(status)
            self._lockouts(status)

    def _lockouts(self, status: Any) -> None:
        for lock in status.lockouts:
            self._announce("lockout", str(lock.process), self._lockout_text(status.dpu, lock))

    def _lockout_text(self, dpu: int, lock: Any) -> str:
        config = self.config(max(self.configs, default=-1))
        names = {p.id: p.name for p in config.processes} if config else {}
        name = names.get(lock.process, f"process {lock.process}")
        text = f"lockout: {name} (DPU {dpu}) at cycle {lock.cycle}"
        if lock.buffer >= 0:
            buffers = {b.id: b.name for b in config.buffers} if config else {}
            text += f", waiting on {buffers.get(lock.buffer, f'buffer {lock.buffer}')}"
        return text

    def _announce(self, kind: str, key: str, text: str) -> None:
        if (kind, key) not in self.announced:
            self.announced.add((kind, key))
            self.faults.append((time.monotonic() - self.started, text))

    def _report(self, data: bytes) -> None:
        report = self._decode(REPORT_CHANNEL, data, skelmsg.report_t.decode)
        if report is not None:
            self.reports.append(report)
            if report.run_id == self.run_id:
                self.last_report = time.monotonic()

    def _config(self, data: bytes) -> None:
        if len(data) < 16 or data[:8] != _CONFIG_FP:
            self._bad(CONFIG_CHANNEL)
            return
        generation = _CONFIG_HEAD.unpack_from(data, 8)[0]
        if self.configs.get(generation) != data:
            self.configs[generation] = data
            self.decoded.pop(generation, None)

    def config(self, generation: int) -> Any:
        """The config_t of a generation, decoded once (it is re-sent every second)."""
        if generation not in self.decoded and generation in self.configs:
            self.decoded[generation] = self._decode(CONFIG_CHANNEL, self.configs[generation],
                                                    skelmsg.config_t.decode)
        return self.decoded.get(generation)

    def ended(self) -> bool:
        """Every DPU of the run sent its report_t (and the grace passed), or the timing
        stopped for QUIET_S, or a newer run began."""
        if self.store is None:
            return False
        now = time.monotonic()
        if self.next_run is not None or (self.last_timing and now - self.last_timing > QUIET_S):
            return True
        config = self.config(max(self.generations, default=-1))
        reported = {r.dpu for r in self.reports if r.run_id == self.run_id}
        everyone = bool(config and reported >= {d.id for d in config.dpus})
        return everyone and now - self.last_report > REPORT_GRACE_S

    def absorb(self) -> None:
        """Decode the timing batches that came since the last call (cheap: those only)."""
        if self.store is not None:
            self.store.add(self.pending)
        self.pending = []

    def snapshot(self) -> RunReport | None:
        """The report of the records heard so far (None before a run and its config)."""
        if self.store is None:
            return None
        self.absorb()
        self.covered = self.store.n_records
        expected = {r.dpu: r.timing_batches for r in self.reports if r.run_id == self.run_id}
        run = self.store.run(expected)
        config = self.config(max(run.generations)) if run.generations else None
        if config is None:
            return None
        timing_bad = self.malformed.get(TIMING_CHANNEL, 0) + run.malformed
        report = build_report(config, run, self.statuses, self.reports, None,
                              {**self.malformed, TIMING_CHANNEL: timing_bad})
        for fault in report.faults:
            # Lockouts come from status_t, at once; "no timing records" is only a fault
            # once the run is over (a slow DPU's first batch may still be on its way).
            if fault.kind != "lockout" and (fault.kind != "dpu_lost" or self.ended()):
                self._announce(fault.kind, f"{fault.process}/{fault.dpu}", _fault_text(fault))
        self._silent_dpus(config)
        return report

    def _silent_dpus(self, config: Any) -> None:
        """A DPU whose heartbeat stopped while the others' timing still flows is lost."""
        now = time.monotonic()
        if now - self.last_timing > HEARTBEAT_LOST_S:
            return  # the whole run stopped (or the replay ended): nobody is lost
        for dpu in sorted(d.id for d in config.dpus):
            last = self.heartbeat.get(dpu)
            if last is not None and now - last > HEARTBEAT_LOST_S:
                self._announce("dpu_lost", str(dpu), f"dpu_lost: DPU {dpu} stopped answering")

    def final(self) -> RunReport:
        """`skel report`'s analysis over an in-memory log of everything heard."""
        from ..read.logreader import encode_events, read_bytes

        return analyze_log(read_bytes(encode_events(self.events), "<heard>"), self.run_id).report


def _fault_text(fault: Any) -> str:
    where = f"{fault.process} (DPU {fault.dpu})" if fault.process else f"DPU {fault.dpu}"
    if fault.kind == "jam":
        return f"jam: {' -> '.join(fault.chain)}: {fault.detail}"
    if fault.kind == "overrun":
        return f"overrun: {where} from cycle {fault.cycle}"
    return f"{fault.kind}: {where}: {fault.detail}"


# --- the command ------------------------------------------------------------------------


def _subscribe(url: str, heard: Heard) -> Any:
    import lcm

    lc = lcm.LCM(url)
    for channel in CHANNELS:
        sub = lc.subscribe(channel, heard.handle)
        sub.set_queue_capacity(0)  # unlimited: LCM would drop the newest batches when full
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


def watch_command(url: str, once: bool, duration_s: float | None) -> int:
    """`skel watch [--url URL] [--once] [--duration S]`: 0; 3 (--once) on a lockout or jam;
    1 when --once heard no run; 2 on a bad URL; 130 when ended by Ctrl-C or SIGTERM."""
    heard = Heard(keep_events=once)
    try:
        lc = _subscribe(url, heard)
    except Exception as e:  # lcm raises IOError/ValueError for a URL it cannot open
        print(f"skel watch: cannot open LCM URL {url}: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    deadline = None if duration_s is None else time.monotonic() + duration_s
    try:
        if once:
            return _once(lc, heard, url, deadline)
        _live(lc, heard, url, deadline)
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    return EXIT_OK


def _live(lc: Any, heard: Heard, url: str, deadline: float | None) -> None:
    console = Console()
    report, due = None, 0.0
    with Live(render(heard, None, url), console=console, auto_refresh=False, transient=False) as live:
        while deadline is None or time.monotonic() < deadline:
            tick = time.monotonic() + REFRESH_S
            _pump(lc, tick if deadline is None else min(tick, deadline))
            heard.absorb()
            if report is not None and report.run_id != heard.run_id:
                report, due = None, 0.0  # a new run: the old tables are not its tables
            start = time.monotonic()
            if start >= due:
                # The tables cost O(records so far): once they take more than a third of
                # the time, recompute less often; the view (records, faults, states)
                # still refreshes every REFRESH_S.
                report = heard.snapshot() or report
                due = start + 2 * (time.monotonic() - start)
            live.update(render(heard, report, url), refresh=True)


def _once(lc: Any, heard: Heard, url: str, deadline: float | None) -> int:
    # Subscribed: say so, so a script may start a replay now without losing its first messages.
    print(f"skel watch: waiting for a run on {url}", file=sys.stderr, flush=True)
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
        report = heard.final()
    except LogError as e:
        print(f"skel watch: run {heard.run_id}: {e}", file=sys.stderr)
        return EXIT_FAILED
    from .tables import print_report

    print_report(report)
    return EXIT_FATAL_FLAW if report.fatal else EXIT_OK
