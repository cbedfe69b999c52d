"""Talking to the DPUs: config broadcast, commands and pings.

One `Control` sends on the control URL, where the DPUs listen, and hears on the
record URL (host/sysfile/link.py: record_url), where they send heartbeats, timing and
reports; a thread drains that into the Listener it is (listener.py: what the
heartbeats, reports and configs say, decoded once and kept). Everything it asks
goes out as config_t and command_t, on both URLs: the DPUs act on the one, the
logger records the other. Commands are repeated a few times (multicast may lose
one) and the DPUs act on each command sequence number once.
"""

from __future__ import annotations

import math
import os
import secrets
import signal
import socket
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field

import lcm

import skelmsg
from skeleton.analysis.errors import SkelError
from skeleton.analysis.read.seal import Signer
from skelmsg import contract

from ..sysfile.link import record_listen_url, record_url, rmem_max
from .listener import CHANNELS, Listener, is_generation

COMMAND_REPEATS = 3
CLOCK_OFFSET_MAX_NS = 2**62  # |DPU clock - host clock|; a clock_offset_t holds it with room to spare


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
    key_problems: dict[int, str] = field(default_factory=dict)  # DPU -> why its key and ours disagree
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
            after = (f": {self.key_problems[d]}" if d in self.key_problems
                     else f": it keeps {self._kept(d)}" if d in self.kept else " (is it up? `skel status`)")
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


class ControlError(SkelError):
    """The control URL cannot be used on this host: one line for the user."""


def subscribe(bus: lcm.LCM, url: str, channels: Iterable[str], handler: Callable[[str, bytes], None]) -> None:
    """HANDLER for every channel of CHANNELS, each with an unbounded queue (LCM would drop the
    newest messages when one is full); ControlError when the URL's port is taken."""
    for channel in channels:
        subscription = bus.subscribe(channel, handler)
        if subscription is None:  # LCM said why on stderr ("bind: Address already in use")
            raise ControlError(f"cannot receive on {url}: its port is taken by another program")
        subscription.set_queue_capacity(0)


class Control(Listener):
    """The host's side of the control channels: it hears as a Listener and sends."""

    def __init__(self, url: str, key: bytes | None = None) -> None:
        super().__init__(key=key)
        self.url = url
        # Who we are on the wire: a run belongs to the session that started it (dpu/owner.c).
        # With a key it is also the sender id of our seals.
        self.session = secrets.randbits(62) + 1
        self._signer = Signer(key, self.session) if key is not None else None
        self.sender = f"{socket.gethostname()} pid {os.getpid()}"
        self.force = False  # `--force`: act during another session's run
        try:
            self.record_url = record_url(url)
        except ValueError as exc:
            raise ControlError(str(exc)) from None
        self.listen_url = record_listen_url(url, rmem_max())  # the record URL, a socket buffer asked
        self._record = lcm.LCM(self.listen_url)
        # Only sends: no socket on the control port. (Another provider than udpm has no ports:
        # its record URL is the control URL, one instance.)
        self._lcm = self._record if self.record_url == url else lcm.LCM(url)
        # seq of each PING we sent -> the first answer of each DPU (later heartbeats repeat it),
        # and -> its t1, which an answer must echo.
        self._pings: dict[int, dict[int, PingSample]] = {}
        self._ping_t1: dict[int, int] = {}
        subscribe(self._record, self.record_url, CHANNELS, self.handle)
        self._running = True
        self._thread = threading.Thread(target=self._drain, name="lcm-control", daemon=True)
        self._thread.start()

    # --- receiving ----------------------------------------------------------------
    def _drain(self) -> None:
        # Ctrl-C and SIGTERM go to the main thread, which ends the command: delivered here,
        # they would only cut LCM's wait short, and it reports that as an error.
        signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
        while self._running:
            self._record.handle_timeout(50)

    def status_heard(self, status: skelmsg.status_t, heard_ns: int) -> None:
        answers = self._pings.get(status.ping_seq)
        if answers is not None and status.dpu not in answers:
            sample = PingSample(status.ping_t1_ns, status.ping_t2_ns, status.ping_t3_ns, heard_ns)
            if _plausible(sample, self._ping_t1.get(status.ping_seq)):
                answers[status.dpu] = sample

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
        with self.lock:
            return sorted(wanted - self.dpus.keys())

    def next_generation(self) -> int:
        """One above any generation a DPU has heard of, so every push is new to all.

        Only generations the host tool may have made count: a stray config (a DPU that
        refused or staged it reports its generation) must neither choose our numbers nor
        push them past int64."""
        with self.lock:
            seen = [g for v in self.dpus.values()
                    for g in (v.status.generation, v.status.staged_generation, v.status.rejected_generation)
                    if is_generation(g)]
        return max(seen, default=0) + 1

    def foreign_generations(self, ids: Iterable[int]) -> dict[int, int]:
        """DPUs among `ids` that applied a generation no host tool makes (a stray committed
        config): they take nothing newer until restarted."""
        with self.lock:
            return {i: self.dpus[i].status.generation for i in ids
                    if i in self.dpus and not is_generation(self.dpus[i].status.generation)}

    # --- sending --------------------------------------------------------------------
    def _sign(self, message: skelmsg.config_t | skelmsg.command_t) -> None:
        message.session, message.force, message.sender = self.session, int(self.force), self.sender

    def publish_config(self, config: skelmsg.config_t) -> None:
        config.sent_utc_ns = time.time_ns()
        self._sign(config)
        self._send(contract.CONFIG_CHANNEL, config.encode())

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
            self._send(contract.COMMAND_CHANNEL, data)  # each repeat sealed anew: a newer counter
        return cmd.seq

    def record(self, channel: str, message: object) -> None:
        """For the log only (the record URL): what no DPU acts on."""
        self._record.publish(channel, self._sealed(channel, message.encode()))  # type: ignore[attr-defined]

    def _send(self, channel: str, data: bytes) -> None:
        """To the DPUs first, then the log's copy: the same bytes, seal and all. A copy sealed
        anew would carry a counter no DPU has seen, so the log's last one, played back to
        the DPUs, would pass as new."""
        sealed = self._sealed(channel, data)
        self._lcm.publish(channel, sealed)
        if self._lcm is not self._record:
            self._record.publish(channel, sealed)

    def _sealed(self, channel: str, data: bytes) -> bytes:
        return data if self._signer is None else self._signer.seal(channel, data)

    def ping(self, dpu: int = -1) -> int:
        """Send one PING (not repeated: a lost one is just a lost sample); return its seq.
        The answers are collected by the LCM thread as they arrive: see pongs()."""
        cmd = skelmsg.command_t()
        cmd.seq = time.time_ns()
        cmd.kind = skelmsg.command_t.PING
        cmd.dpu = dpu
        self._sign(cmd)
        with self.lock:
            self._pings[cmd.seq] = {}
        cmd.ping_t1_ns = time.monotonic_ns()
        self._ping_t1[cmd.seq] = cmd.ping_t1_ns  # before the publish, so before any answer
        self._send(contract.COMMAND_CHANNEL, cmd.encode())
        return cmd.seq

    def wait_pongs(self, seqs: Iterable[int], dpus: Iterable[int], timeout_s: float) -> bool:
        """Wait until every DPU in `dpus` answered every ping in `seqs`."""
        seqs, wanted = list(seqs), set(dpus)
        return self.wait_for(lambda: all(wanted <= self._pings.get(s, {}).keys() for s in seqs), timeout_s)

    def pongs(self, seqs: Iterable[int], forget: bool = True) -> dict[int, list[PingSample]]:
        """The answers to the pings `seqs`, per DPU; forget those pings unless told not to."""
        samples: dict[int, list[PingSample]] = {}
        with self.lock:
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
        with self.lock:
            result.key_problems = dict(self.key_problems)
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
