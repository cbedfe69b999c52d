"""Synthetic runs for the analysis tests: real LCM encoding (generated types, lcm.EventLog),
known numbers.

The small system: DPU 1 (minor cycle 10 ms) runs A (4 ms) then B (2 ms, data-
synchronised on A's buffer a_out); DPU 2 (20 ms) runs C (5 ms, reads b_out).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import lcm

import skelmsg
from skelmsg.contract import DEFAULT_URL

RUN_ID = 42
GENERATION = 3
MS = 1_000_000  # ns
US = 1_000


def _process(pid: int, name: str, dpu: int, order: int, period_us: int, compute_us: int,
             inputs: list[int], outputs: list[int], sync: int = 0) -> skelmsg.process_t:  # fmt: skip
    p = skelmsg.process_t()
    p.id, p.name, p.dpu, p.order, p.period_us, p.compute_us, p.sync = (
        pid, name, dpu, order, period_us, compute_us, sync
    )  # fmt: skip
    p.ninputs, p.inputs, p.required = len(inputs), inputs, [1] * len(inputs)
    p.noutputs, p.outputs = len(outputs), outputs
    return p


def small_config(warmup_cycles: int = 2, generation: int = GENERATION) -> skelmsg.config_t:
    c = skelmsg.config_t()
    c.generation, c.run_id, c.committed, c.system = generation, RUN_ID, 1, "small"
    c.warmup_cycles, c.lockout_cycles, c.late_pct, c.too_late_pct = warmup_cycles, 5, 40, 80
    link = skelmsg.link_t()
    link.id, link.name, link.url = 0, "bus", DEFAULT_URL
    c.nlinks, c.links = 1, [link]
    dpus = []
    for did, minor in ((1, 10_000), (2, 20_000)):
        d = skelmsg.dpu_t()
        d.id, d.host, d.cpu, d.compute, d.executive = did, "h", -1, 0, 0
        d.speed, d.minor_cycle_us = 1.0, minor
        d.nlinks, d.links = 1, [0]
        dpus.append(d)
    c.ndpus, c.dpus = 2, dpus
    bufs = []
    for bid, name, writer in ((0, "a_out", 0), (1, "b_out", 1), (2, "c_out", 2)):
        b = skelmsg.buffer_desc_t()
        b.id, b.name, b.bytes, b.link, b.writer, b.channel = bid, name, 64, 0, writer, f"SKEL_BUF_{name}"
        bufs.append(b)
    c.nbuffers, c.buffers = 3, bufs
    procs = [
        _process(0, "A", 1, 0, 10_000, 4_000, [2], [0]),
        _process(1, "B", 1, 1, 10_000, 2_000, [0], [1], sync=1),
        _process(2, "C", 2, 0, 20_000, 5_000, [1], [2], sync=1),
    ]
    c.nprocesses, c.processes = 3, procs
    c.nchains, c.chains = 0, []
    c.source = "system: small\n"
    return c


@dataclass
class Rec:
    """One process-cycle record (times in ns) and its input records."""

    process: int
    cycle: int
    minor: int
    release_ns: int
    start_ns: int
    comm_in_ns: int = 0
    blocked_ns: int = 0
    compute_ns: int = 0
    comm_out_ns: int = 0
    idle_ns: int = 0
    slack_ns: int = 0
    flags: int = 0
    sched_ns: int | None = None  # the schedule's start; None: the release
    stall_ns: int = 0
    debt_ns: int = 0
    # (buffer, seq, new, dropped, received) or (..., sent_ns, recv_ns); without times
    # an input gets sent 1000 + i and received 2000 + i ns (i: its row in the batch)
    inputs: list[tuple[int, ...]] = field(default_factory=list)

    @property
    def end_ns(self) -> int:
        return self.start_ns + self.comm_in_ns + self.blocked_ns + self.compute_ns + self.comm_out_ns


_FIELDS = ("process", "cycle", "minor", "release_ns", "start_ns", "comm_in_ns", "blocked_ns",
           "compute_ns", "comm_out_ns", "idle_ns", "slack_ns", "stall_ns", "flags")  # fmt: skip


def batches(dpu: int, recs: list[Rec], size: int, run_id: int = RUN_ID,
            generation: int = GENERATION, first_seq: int = 0) -> list[skelmsg.timing_t]:  # fmt: skip
    out = []
    for seq, first in enumerate(range(0, len(recs), size), start=first_seq):
        chunk = recs[first : first + size]
        t = skelmsg.timing_t()
        t.dpu, t.run_id, t.generation, t.batch_seq, t.n = dpu, run_id, generation, seq, len(chunk)
        for name in _FIELDS:
            setattr(t, name, [getattr(r, name) for r in chunk])
        t.sched_ns = [r.release_ns if r.sched_ns is None else r.sched_ns for r in chunk]
        t.asked_ns = [r.compute_ns for r in chunk]  # a constant compute, emulated exactly
        t.preemptions, t.preempted_ns = [0] * len(chunk), [0] * len(chunk)  # the cyclic executive
        t.debt_ns = [r.debt_ns for r in chunk]
        t.event_ns = [-1] * len(chunk)  # no sync: event process
        t.event_queued, t.event_dropped = [0] * len(chunk), [0] * len(chunk)
        rows = [(i, *inp) for i, r in enumerate(chunk) for inp in r.inputs]
        t.ninputs = len(rows)
        t.in_record = [r[0] for r in rows]
        t.in_buffer = [r[1] for r in rows]
        t.in_seq = [r[2] for r in rows]
        t.in_new = [r[3] for r in rows]
        t.in_dropped = [r[4] for r in rows]
        t.in_received = [r[5] for r in rows]
        t.in_sent_ns = [r[6] if len(r) > 6 else 1000 + i for i, r in enumerate(rows)]
        t.in_recv_ns = [r[7] if len(r) > 7 else 2000 + i for i, r in enumerate(rows)]
        out.append(t)
    return out


def status(dpu: int, lockouts: list[tuple[int, ...]], run_id: int = RUN_ID) -> skelmsg.status_t:
    """A heartbeat with lockouts [(process, buffer or -1, cycle[, behind])]: behind, the
    process whose data wait held it up, -1 when none (the default)."""
    s = skelmsg.status_t()
    s.dpu, s.host, s.state, s.generation, s.run_id = dpu, "h", 3, GENERATION, run_id
    s.reject_reason = ""
    locks = []
    for proc, buf, cycle, *behind in lockouts:
        lo = skelmsg.lockout_t()
        lo.process, lo.buffer, lo.cycle, lo.release_ns = proc, buf, cycle, 0
        lo.behind = behind[0] if behind else -1
        locks.append(lo)
    s.nlockouts, s.lockouts = len(locks), locks
    return s


def report(dpu: int, timing_batches: int, run_id: int = RUN_ID) -> skelmsg.report_t:
    r = skelmsg.report_t()
    r.dpu, r.run_id, r.generation, r.timing_batches, r.speed = dpu, run_id, GENERATION, timing_batches, 1.0
    r.nprocesses, r.processes = 0, []
    return r


def chain(name: str, processes: list[int]) -> skelmsg.chain_t:
    c = skelmsg.chain_t()
    c.name, c.nprocesses, c.processes = name, len(processes), processes
    return c


def clock_offset(dpu: int, host_mono_ns: int, offset_ns: int) -> skelmsg.clock_offset_t:
    """An estimate of DPU clock - host clock, made at host_mono_ns (host clock)."""
    m = skelmsg.clock_offset_t()
    m.dpu, m.host_mono_ns, m.offset_ns, m.rtt_ns, m.samples = dpu, host_mono_ns, offset_ns, 50_000, 8
    return m


def write_log(path: Path, events: list[tuple[str, Any]]) -> Path:
    """Write (channel, message or raw bytes) events with increasing timestamps."""
    log = lcm.EventLog(str(path), "w", overwrite=True)
    for i, (channel, msg) in enumerate(events):
        data = msg if isinstance(msg, bytes) else msg.encode()
        log.write_event(1_000_000 + i * 100, channel, data)
    log.close()
    return path


def small_run(warmup: int = 2, cycles: int = 10) -> tuple[list[Rec], list[Rec]]:
    """DPU 1 and DPU 2 records with hand-checkable numbers (see test_metrics)."""
    t0 = 5_000 * MS
    dpu1: list[Rec] = []
    for k in range(cycles):
        r = t0 + k * 10 * MS
        warm = k < warmup  # warm-up cycles carry absurd numbers: they must not count
        a_compute = 6 * MS if warm else 4 * MS  # B still ends before the next release, as a DPU's would
        a = Rec(0, k, k, r, r + (100 + 10 * k) * US, 200 * US, 0, a_compute, 300 * US)
        a.slack_ns = r + 10 * MS - a.end_ns
        a.inputs = [(2, k - 1, 1, 0, 1)]
        b_start = a.end_ns + 100 * US
        b = Rec(1, k, k, r, b_start, 100 * US, 500 * US, 2 * MS, 200 * US)
        b.idle_ns = max(r + 10 * MS - b.end_ns, 0)  # a DPU's idle is never negative
        b.slack_ns = b.idle_ns
        new = 0 if k in (4, 7) else 1
        b.inputs = [(0, k, new, 2 if k == 5 else 0, new)]
        dpu1 += [a, b]
    dpu2: list[Rec] = []
    for k in range(cycles // 2):
        r = t0 + k * 20 * MS
        c = Rec(2, k, k, r, r + 50 * US, 100 * US, 1 * MS, 5 * MS, 100 * US)
        c.idle_ns = r + 20 * MS - c.end_ns
        c.slack_ns = c.idle_ns
        if k == cycles // 2 - 1:  # one overrun, in the last (measured) cycle
            c.compute_ns = 19 * MS
            c.slack_ns = r + 20 * MS - c.end_ns
            c.idle_ns = 0
            c.flags = skelmsg.timing_t.FLAG_OVERRUN
        c.inputs = [(1, 2 * k, 1, 1, 2)]
        dpu2.append(c)
    return dpu1, dpu2
