"""Talking to the DPUs: config broadcast, commands, and what their heartbeats say.

One `Control` owns one LCM instance on the control URL and a thread that drains
it. Everything the host knows about the DPUs comes from their status_t
heartbeats and report_t messages; everything it asks goes out as config_t and
command_t. Commands are repeated a few times (multicast may lose one) and the
DPUs act on each command sequence number once.
"""

from __future__ import annotations

import math
import os
import secrets
import signal
import socket
import struct
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import lcm

import skelmsg
from skelmsg import contract

STATE_NAMES = {
    skelmsg.status_t.STATE_UNCONFIGURED: "unconfigured",
    skelmsg.status_t.STATE_READY: "ready",
    skelmsg.status_t.STATE_ARMED: "armed",
    skelmsg.status_t.STATE_RUNNING: "running",
}
COMMAND_REPEATS = 3
HEARTBEAT_S = contract.STATUS_PERIOD_MS / 1000  # a DPU heartbeats at 5 Hz ...
LOST_AFTER_S = 0.6          # ... three missed beats and it is reported lost
# `skel status`/`skel clock` listen until no DPU not heard before has been heard for this
# long (five heartbeats: a DPU that is up is heard even when a beat or two are lost).
QUIET_S = 5 * HEARTBEAT_S
# Pushed configs kept (by generation) so a running follower can re-send the one committed mid-run.
CONFIGS_KEPT = 4
# What anyone on the group may send is bounded before the host tool keeps or uses it: a stray
# generation of 2**63-1 once made every later push overflow int64. The host's own generations
# count pushes and its run ids are milliseconds since 1970: both far inside these ranges
# (integers a JSON reader or a double holds exactly).
GENERATION_MAX = 2**53 - 1
RUN_ID_MAX = 2**53 - 1
CLOCK_OFFSET_MAX_NS = 2**62  # |DPU clock - host clock|; a clock_offset_t holds it with room to spare
REPORTS_KEPT = 1024          # report_t kept, newest first out: a flood of them cannot grow memory
PROCESSES_KEPT = 4096        # daemons (host, pid) remembered for `skel status`, likewise


@dataclass(frozen=True)
class PingSample:
    """One ping/pong: t1 host send, t2 DPU receive, t3 DPU reply, t4 host receive (ns)."""

    t1: int
    t2: int
    t3: int
    t4: int

    @property
    def offset_ns(self) -> int:
        """DPU clock minus host clock, assuming the two legs take equally long."""
        return ((self.t2 - self.t1) + (self.t3 - self.t4)) // 2

    @property
    def rtt_ns(self) -> int:
        """Time on the wire (both legs), the DPU's own handling time taken out."""
        return (self.t4 - self.t1) - (self.t3 - self.t2)


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


@dataclass
class PushResult:
    """What every DPU did with one pushed generation. Each DPU is in exactly one of
    applied, staged (accepted, not applied: not committed, or the switch not seen),
    rejected (with its reason) or silent (never answered)."""

    generation: int
    applied: list[int] = field(default_factory=list)
    rejected: dict[int, str] = field(default_factory=dict)
    silent: list[int] = field(default_factory=list)
    staged: list[int] = field(default_factory=list)
    kept: dict[int, int] = field(default_factory=dict)  # DPU -> the generation it applies at the end
    states: dict[int, str] = field(default_factory=dict)  # DPU -> its state at the end
    at_utc_ns: int = 0          # when the commit takes effect (0: at once)
    committed: bool = False     # the COMMIT was sent (every DPU had staged the generation)

    @property
    def ok(self) -> bool:
        return not self.rejected and not self.silent and not (self.committed and self.staged)

    def outcome(self) -> list[tuple[bool, str]]:
        """One line per DPU, saying what it applies now, then whether anything was
        committed: (fine, text)."""
        g = self.generation
        lines = [(True, f"DPU {d}: applied generation {g}") for d in self.applied]
        for d in self.staged:
            if self.committed:
                text = (f"staged generation {g} but did not apply it: it still applies {self._kept(d)} "
                        f"({self.states.get(d, 'not heard')})")
            else:
                text = f"staged generation {g}, not applied: it keeps {self._kept(d)}"
            lines.append((False, f"DPU {d}: {text}"))
        for d, reason in sorted(self.rejected.items()):
            lines.append((False, f"DPU {d}: rejected generation {g}: {reason}"))
        for d in self.silent:
            after = f": it keeps {self._kept(d)}" if d in self.kept else " (is it up? `skel status`)"
            lines.append((False, f"DPU {d}: did not answer generation {g}{after}"))
        if not self.committed:
            lines.append((False, "nothing was committed: every DPU keeps its previous configuration"))
        elif not self.ok:
            lines.append((False, f"generation {g} was committed: applied by DPU {_ids(self.applied)}; "
                                 f"not by DPU {_ids(self.staged + self.silent)}"))
        return lines

    def _kept(self, dpu: int) -> str:
        generation = self.kept.get(dpu, 0)
        return f"generation {generation}" if generation > 0 else "no configuration"


def _ids(ids: Iterable[int]) -> str:
    return ", ".join(map(str, sorted(ids))) or "none"


def _reached(dpu_generation: int, generation: int) -> bool:
    """The DPU has `generation` or a newer one a host tool made (a stray 2**63-1 is not newer)."""
    return is_generation(dpu_generation) and dpu_generation >= generation


def _plausible(sample: PingSample, t1_sent: int | None) -> bool:
    """An answer to our ping: it echoes our t1, the DPU replied after it received, within
    our round trip, and the offset fits a clock_offset_t."""
    return (sample.t1 == t1_sent and 0 <= sample.t3 - sample.t2 <= sample.t4 - sample.t1
            and abs(sample.offset_ns) <= CLOCK_OFFSET_MAX_NS)


class Control:
    """The host's side of the control channels."""

    def __init__(self, url: str) -> None:
        self.url = url
        # Who we are on the wire: a run belongs to the session that started it (dpu/owner.c).
        self.session = secrets.randbits(62) + 1
        self.sender = f"{socket.gethostname()} pid {os.getpid()}"
        self.force = False  # `--force`: act during another session's run
        self._lcm = lcm.LCM(url)
        self._lock = threading.Lock()
        self._changed = threading.Condition(self._lock)
        self.dpus: dict[int, DpuView] = {}
        # Every daemon heard, by (host, pid): DPUs started with --id auto all heartbeat as
        # DPU -1 until a config names them, and two daemons may claim one id.
        self.processes: dict[tuple[str, int], DpuView] = {}
        self._new_process_mono = time.monotonic()   # when the last daemon not heard before was
        self.reports: dict[tuple[int, int], skelmsg.report_t] = {}
        self.rejected_messages = 0
        self.on_status: Callable[[skelmsg.status_t], None] | None = None
        # Every config heard on the wire (ours and other `skel push`es'), newest generations only.
        self.configs: dict[int, skelmsg.config_t] = {}
        # seq of each PING we sent -> the first answer of each DPU (later heartbeats repeat it),
        # and -> its t1, which an answer must echo.
        self._pings: dict[int, dict[int, PingSample]] = {}
        self._ping_t1: dict[int, int] = {}
        for channel, handler in ((contract.STATUS_CHANNEL, self._handle_status),
                                 (contract.REPORT_CHANNEL, self._handle_report),
                                 (contract.CONFIG_CHANNEL, self._handle_config)):
            self._lcm.subscribe(channel, handler).set_queue_capacity(0)
        self._running = True
        self._thread = threading.Thread(target=self._drain, name="lcm-control", daemon=True)
        self._thread.start()

    # --- receiving ----------------------------------------------------------------
    def _drain(self) -> None:
        # Ctrl-C and SIGTERM go to the main thread, which ends the command: delivered here,
        # they would only cut LCM's wait short, and it reports that as an error.
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        while self._running:
            self._lcm.handle_timeout(50)

    def _decode(self, cls: type, data: bytes) -> object | None:
        """Decode, or count a malformed/foreign message and return None: never crash."""
        try:
            return cls.decode(data)
        except (ValueError, struct.error, UnicodeDecodeError, IndexError):
            with self._lock:
                self.rejected_messages += 1
            return None

    def _refuse(self) -> None:
        with self._lock:
            self.rejected_messages += 1

    def _handle_status(self, _channel: str, data: bytes) -> None:
        # t4 of a ping: first thing, before decoding, so only the wire and LCM are in the round trip.
        t4 = time.monotonic_ns()
        status = self._decode(skelmsg.status_t, data)
        if not isinstance(status, skelmsg.status_t):
            return
        if not (status.dpu == -1 or status.dpu > 0):  # ids are 1..32767, -1 before --id auto found its own
            self._refuse()
            return
        now = time.monotonic()
        with self._changed:
            view = DpuView(status, now)
            self.dpus[status.dpu] = view
            key = (status.host, status.pid)
            if key not in self.processes:
                self._new_process_mono = now
                if len(self.processes) >= PROCESSES_KEPT:
                    del self.processes[next(iter(self.processes))]
            self.processes[key] = view
            answers = self._pings.get(status.ping_seq)
            if answers is not None and status.dpu not in answers:
                sample = PingSample(status.ping_t1_ns, status.ping_t2_ns, status.ping_t3_ns, t4)
                if _plausible(sample, self._ping_t1.get(status.ping_seq)):
                    answers[status.dpu] = sample
            self._changed.notify_all()
        if self.on_status is not None:
            self.on_status(status)

    def _handle_report(self, _channel: str, data: bytes) -> None:
        report = self._decode(skelmsg.report_t, data)
        if not isinstance(report, skelmsg.report_t):
            return
        if report.dpu <= 0 or not is_run_id(report.run_id):
            self._refuse()
            return
        with self._changed:
            self.reports.pop((report.dpu, report.run_id), None)
            self.reports[(report.dpu, report.run_id)] = report
            while len(self.reports) > REPORTS_KEPT:
                del self.reports[next(iter(self.reports))]
            self._changed.notify_all()

    def _handle_config(self, _channel: str, data: bytes) -> None:
        config = self._decode(skelmsg.config_t, data)
        if not isinstance(config, skelmsg.config_t):
            return
        if not is_generation(config.generation):  # not one of ours, and it would crowd ours out
            self._refuse()
            return
        with self._changed:
            self.configs[config.generation] = config
            for old in sorted(self.configs)[:-CONFIGS_KEPT]:
                del self.configs[old]
            self._changed.notify_all()

    def config_of(self, generation: int) -> skelmsg.config_t | None:
        """The config of `generation` if it was heard on the wire (pushed by any host)."""
        with self._lock:
            return self.configs.get(generation)

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float) -> bool:
        """Wait until predicate() (evaluated under the lock) holds, or time out."""
        deadline = time.monotonic() + timeout_s
        with self._changed:
            while not predicate():
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._changed.wait(min(left, 0.1))
        return True

    def snapshot(self) -> dict[int, DpuView]:
        with self._lock:
            return dict(self.dpus)

    def listen(self, limit_s: float, quiet_s: float = QUIET_S) -> float:
        """Listen until no daemon not heard before has been heard for `quiet_s` (from the
        start, or from the last new one), or `limit_s` in all; the seconds listened."""
        start = time.monotonic()
        self.wait_for(lambda: time.monotonic() - max(start, self._new_process_mono) >= quiet_s,
                      limit_s)
        return time.monotonic() - start

    def daemons(self) -> list[DpuView]:
        """The latest heartbeat of every daemon heard, by DPU id, then host and pid."""
        with self._lock:
            views = list(self.processes.values())
        return sorted(views, key=lambda v: (v.status.dpu, v.status.host, v.status.pid))

    def lost(self, ids: Iterable[int]) -> list[int]:
        """DPUs among `ids` not heard for LOST_AFTER_S (or never)."""
        now = time.monotonic()
        with self._lock:
            return [i for i in ids if i not in self.dpus or now - self.dpus[i].heard_mono > LOST_AFTER_S]

    def wait_heard(self, ids: Iterable[int], timeout_s: float,
                   introduce: Callable[[int], skelmsg.config_t] | None = None) -> list[int]:
        """Wait until every DPU in `ids` has sent a heartbeat; return the silent ones.

        A DPU started with `--id auto` heartbeats as DPU -1 until a config names its host.
        With `introduce` (generation -> config), such a DPU is sent the config, staged
        only, so it finds itself and answers under its id."""
        wanted = set(ids)
        deadline = time.monotonic() + timeout_s
        generation = None
        while not self.wait_for(lambda: wanted <= self.dpus.keys(), min(0.25, deadline - time.monotonic())):
            if time.monotonic() >= deadline:
                break
            if introduce is not None and -1 in self.dpus:
                generation = generation or self.next_generation()
                self.publish_config(introduce(generation))
        with self._lock:
            return sorted(wanted - self.dpus.keys())

    def next_generation(self) -> int:
        """One above any generation a DPU has heard of, so every push is new to all.

        Only generations the host tool may have made count: a stray config (a DPU that
        refused or staged it reports its generation) must neither choose our numbers nor
        push them past int64."""
        with self._lock:
            seen = [g for v in self.dpus.values()
                    for g in (v.status.generation, v.status.staged_generation, v.status.rejected_generation)
                    if is_generation(g)]
        return max(seen, default=0) + 1

    def foreign_generations(self, ids: Iterable[int]) -> dict[int, int]:
        """DPUs among `ids` that applied a generation no host tool makes (a stray committed
        config): they take nothing newer until restarted."""
        with self._lock:
            return {i: self.dpus[i].status.generation for i in ids
                    if i in self.dpus and not is_generation(self.dpus[i].status.generation)}

    # --- sending --------------------------------------------------------------------
    def _sign(self, message: skelmsg.config_t | skelmsg.command_t) -> None:
        message.session, message.force, message.sender = self.session, int(self.force), self.sender

    def publish_config(self, config: skelmsg.config_t) -> None:
        config.sent_utc_ns = time.time_ns()
        self._sign(config)
        self._lcm.publish(contract.CONFIG_CHANNEL, config.encode())

    def command(self, kind: int, dpu: int = -1, repeats: int = COMMAND_REPEATS, **fields: int) -> int:
        """Send one command (`repeats` times, same seq); return its seq."""
        cmd = skelmsg.command_t()
        # Wall-clock sequence numbers stay increasing across separate `skel` invocations.
        cmd.seq = time.time_ns()
        cmd.kind = kind
        cmd.dpu = dpu
        self._sign(cmd)
        for name, value in fields.items():
            setattr(cmd, name, value)
        data = cmd.encode()
        for i in range(repeats):
            if i:
                time.sleep(0.01)
            self._lcm.publish(contract.COMMAND_CHANNEL, data)
        return cmd.seq

    def publish(self, channel: str, message: object) -> None:
        self._lcm.publish(channel, message.encode())  # type: ignore[attr-defined]

    def ping(self, dpu: int = -1) -> int:
        """Send one PING (not repeated: a lost one is just a lost sample); return its seq.
        The answers are collected by the LCM thread as they arrive: see pongs()."""
        cmd = skelmsg.command_t()
        cmd.seq = time.time_ns()
        cmd.kind = skelmsg.command_t.PING
        cmd.dpu = dpu
        self._sign(cmd)
        with self._lock:
            self._pings[cmd.seq] = {}
        cmd.ping_t1_ns = time.monotonic_ns()
        self._ping_t1[cmd.seq] = cmd.ping_t1_ns  # before the publish, so before any answer
        self._lcm.publish(contract.COMMAND_CHANNEL, cmd.encode())
        return cmd.seq

    def wait_pongs(self, seqs: Iterable[int], dpus: Iterable[int], timeout_s: float) -> bool:
        """Wait until every DPU in `dpus` answered every ping in `seqs`."""
        seqs, wanted = list(seqs), set(dpus)
        return self.wait_for(lambda: all(wanted <= self._pings.get(s, {}).keys() for s in seqs), timeout_s)

    def pongs(self, seqs: Iterable[int], forget: bool = True) -> dict[int, list[PingSample]]:
        """The answers to the pings `seqs`, per DPU; forget those pings unless told not to."""
        samples: dict[int, list[PingSample]] = {}
        with self._lock:
            for seq in seqs:
                answers = self._pings.pop(seq, {}) if forget else dict(self._pings.get(seq, {}))
                if forget:
                    self._ping_t1.pop(seq, None)
                for dpu, sample in answers.items():
                    samples.setdefault(dpu, []).append(sample)
        return samples

    def push(self, config: skelmsg.config_t, dpus: Iterable[int], timeout_s: float = 3.0,
             at_ms: float | None = None) -> PushResult:
        """Stage a config on every DPU, then commit it only if all of them accepted it.

        With `at_ms`, the COMMIT names the instant `at_ms` after it is sent: DPUs in a run
        switch at the first boundary at or after it of the grid their minor cycles share
        (dpu/swap.c), all at one instant. Without, it takes effect at once (between runs)."""
        wanted = sorted(set(dpus))
        generation = config.generation
        result = PushResult(generation)

        def settled() -> bool:
            return all(
                i in self.dpus and (_reached(self.dpus[i].status.staged_generation, generation)
                                    or _reached(self.dpus[i].status.generation, generation)
                                    or self.dpus[i].status.rejected_generation == generation)
                for i in wanted)

        config.committed = 0
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline and not settled():
            self.publish_config(config)
            self.wait_for(settled, 0.25)
        self._settle(result, wanted)
        if result.rejected or result.silent:
            return result
        if at_ms is not None:
            result.at_utc_ns = time.time_ns() + int(at_ms * 1e6)
        self.command(skelmsg.command_t.COMMIT, generation=generation, at_utc_ns=result.at_utc_ns)
        result.committed = True
        # The switch waits for the DPUs' common grid (their minor cycles' lcm, unused past MAX_COMMON_US).
        grid_us = math.lcm(*(d.minor_cycle_us for d in config.dpus if d.minor_cycle_us > 0))
        until_switch_s = (max(0.0, (result.at_utc_ns - time.time_ns()) / 1e9)
                          + min(grid_us, contract.MAX_COMMON_US) / 1e6)
        self.wait_for(lambda: all(_reached(self.dpus[i].status.generation, generation) for i in wanted),
                      until_switch_s + timeout_s)
        self._settle(result, wanted)
        return result

    def _settle(self, result: PushResult, wanted: list[int]) -> None:
        """Sort every wanted DPU by what its last heartbeat says about result.generation."""
        generation = result.generation
        result.applied, result.staged, result.silent, result.rejected = [], [], [], {}
        snapshot = self.snapshot()
        for i in wanted:
            view = snapshot.get(i)
            if view is None:
                result.silent.append(i)
                continue
            result.kept[i], result.states[i] = view.status.generation, view.state
            if _reached(view.status.generation, generation):
                result.applied.append(i)
            elif view.status.rejected_generation == generation:
                result.rejected[i] = view.status.reject_reason or "rejected"
            elif _reached(view.status.staged_generation, generation):
                result.staged.append(i)
            else:
                result.silent.append(i)

    def start(self, generation: int, run_id: int, at_utc_ns: int, duration_ns: int) -> None:
        self.command(skelmsg.command_t.START, generation=generation, run_id=run_id,
                     at_utc_ns=at_utc_ns, duration_ns=duration_ns)

    def stop(self) -> None:
        self.command(skelmsg.command_t.STOP)

    def shutdown(self, dpu: int = -1) -> None:
        self.command(skelmsg.command_t.SHUTDOWN, dpu=dpu)

    def close(self) -> None:
        self._running = False
        self._thread.join(timeout=1.0)
