"""Fatal flaws: process lockouts, pipeline jams (with the chain back to the root
cause), overruns and lost DPUs. Definitions only; inputs are decoded messages,
record arrays and a config_t, as in metrics.py.

What holds a locked-out process up, in order: the required input its DPU said it
waits on; the process of its DPU whose data wait held it up (the cyclic executive
is one thread: while one process waits, none of the others runs); for a
data-synchronised process, a required input whose writer is locked out too (it
cannot complete a cycle without that writer's new data). A jam is a chain of such
links between locked-out processes."""

from __future__ import annotations

import itertools
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

import skelmsg

from .metrics import ProcessMetrics, static_load_pct
from .records import FLAG_LOCKOUT


@dataclass
class Fault:
    kind: str  # "lockout" | "jam" | "overrun" | "dpu_lost"
    process: str | None = None
    dpu: int | None = None
    buffer: str | None = None
    writer: str | None = None
    cycle: int | None = None
    chain: list[str] = field(default_factory=list)  # jam: head ... root cause
    detail: str = ""
    count: int | None = None  # overrun: how many
    static_load_pct: float | None = None  # jam: static load of the root cause's DPU
    root_dpu: int | None = None  # jam: the DPU of the chain's last process


@dataclass(frozen=True)
class Lockout:
    process: int
    buffer: int | None  # the required input it waits on; None when not waiting for data
    cycle: int
    known_wait: bool = True  # False when only a timing record's flag told us
    behind: int | None = None  # the process of its DPU whose data wait held it up


@dataclass(frozen=True)
class Heartbeat:
    """One status_t as heard: when (one clock for every DPU: the logger's), from which
    daemon, in which run and state."""

    dpu: int
    heard_us: int | None  # None: not known (a live view keeps no times)
    pid: int
    run_id: int
    state: int


def heartbeats_from_status(timed: Iterable[tuple[int | None, Any]]) -> list[Heartbeat]:
    """(heard_us or None, status_t) pairs, as a log gives them, to heartbeats in time order."""
    beats = [Heartbeat(int(s.dpu), None if t is None else int(t), int(s.pid), int(s.run_id), int(s.state))
             for t, s in timed]
    return sorted(beats, key=lambda h: -1 if h.heard_us is None else h.heard_us)


def lockouts_from_status(statuses: Iterable[Any], run_id: int) -> dict[int, Lockout]:
    """status_t.lockouts[] of one run, first report of each process kept."""
    out: dict[int, Lockout] = {}
    for status in statuses:
        if status.run_id != run_id:
            continue
        for lock in status.lockouts:
            if lock.process not in out:
                buffer = None if lock.buffer < 0 else int(lock.buffer)
                behind = None if lock.behind < 0 else int(lock.behind)
                out[int(lock.process)] = Lockout(int(lock.process), buffer, int(lock.cycle), behind=behind)
    return out


def lockouts_from_records(records: np.ndarray, known: dict[int, Lockout]) -> dict[int, Lockout]:
    """Add processes whose timing records carry FLAG_LOCKOUT but no status_t said so
    (status heartbeats lost): what they waited on is then unknown."""
    out = dict(known)
    flagged = records[(records["flags"] & FLAG_LOCKOUT) != 0]
    for proc in np.unique(flagged["process"]).tolist():
        if proc not in out:
            first = int(flagged["cycle"][flagged["process"] == proc].min())
            out[proc] = Lockout(proc, None, first, known_wait=False)
    return out


def lockout_faults(lockouts: dict[int, Lockout], config: Any) -> list[Fault]:
    names, dpus, buffers = _index(config)
    faults = []
    for proc in sorted(lockouts):
        lock = lockouts[proc]
        if lock.buffer is not None:
            detail = f"waits on {_bname(buffers, lock.buffer)}"
        elif lock.behind is not None:
            detail = (f"held up behind {names.get(lock.behind, f'process {lock.behind}')}, which waits "
                      f"for data on the same DPU: its one thread runs neither")
        elif lock.known_wait:
            detail = "not waiting for data: its DPU cannot run it"
        else:
            detail = "flagged in the timing records (no status_t)"
        faults.append(Fault(kind="lockout", detail=detail, **_where(proc, lock, names, dpus, buffers)))
    return faults


def _where(proc: int, lock: Lockout, names: dict[int, str], dpus: dict[int, int],
           buffers: dict[int, Any]) -> dict[str, Any]:
    """A locked-out process's fault fields: who, where, what it waits on and from whom."""
    buf = buffers.get(lock.buffer) if lock.buffer is not None else None
    return {
        "process": names.get(proc, f"process {proc}"),
        "dpu": dpus.get(proc),
        "buffer": None if lock.buffer is None else _bname(buffers, lock.buffer),
        "writer": None if buf is None else names.get(buf.writer, f"process {buf.writer}"),
        "cycle": lock.cycle,
    }


@dataclass(frozen=True)
class _Hold:
    """What holds a locked-out process up: a process, through a buffer or not."""

    process: int | None = None
    buffer: int | None = None
    how: str = ""


def _holder(proc: int, lockouts: dict[int, Lockout], config: Any) -> _Hold:
    """What holds locked-out `proc` up (see the module comment)."""
    names, dpus, buffers = _index(config)
    lock = lockouts[proc]

    def name(p: int) -> str:
        return names.get(p, f"process {p}")

    if lock.buffer is not None:
        buf = buffers.get(lock.buffer)
        if buf is None:
            return _Hold()
        how = f"{name(proc)} waits on {buf.name} from {name(buf.writer)}"
        return _Hold(int(buf.writer), lock.buffer, how)
    if lock.behind is not None:
        return _Hold(lock.behind, None,
                     f"{name(proc)} is held up behind {name(lock.behind)} on DPU {dpus.get(proc)}")
    desc = next((p for p in config.processes if p.id == proc), None)
    if desc is None or desc.sync != skelmsg.process_t.SYNC_DATA:
        return _Hold()
    for buffer_id, required in zip(desc.inputs, desc.required, strict=False):
        buf = buffers.get(buffer_id)
        if required and buf is not None and buf.writer in lockouts:
            how = f"{name(proc)} needs new {buf.name} from {name(buf.writer)}"
            return _Hold(int(buf.writer), int(buffer_id), how)
    return _Hold()


def jam_faults(lockouts: dict[int, Lockout], config: Any) -> list[Fault]:
    """A jam: a locked-out process held up by another locked-out process.

    One fault per chain, reported from its head (a jammed process nobody jammed
    waits on) back to the root cause: a locked-out process not waiting for data (its
    DPU is overloaded), a writer that is not locked out, or a circular wait."""
    names, dpus, buffers = _index(config)
    holders = {p: _holder(p, lockouts, config) for p in lockouts}

    def writer_of(proc: int) -> int | None:
        return holders[proc].process

    jammed = {p for p in lockouts if (w := writer_of(p)) is not None and w in lockouts}
    waited_on = {writer_of(p) for p in jammed}
    heads = sorted(p for p in jammed if p not in waited_on)
    covered: set[int] = set()
    faults = []
    for head in heads + sorted(jammed):  # then circular waits, which have no head
        if head in covered:
            continue
        chain = [head]
        while (w := writer_of(chain[-1])) is not None and w in lockouts and w not in chain:
            chain.append(w)
        covered.update(chain)
        root = chain[-1]
        w = writer_of(root)
        load = None
        if w is not None and w in chain:
            chain.append(w)
            cycle = chain[chain.index(w) :]
            cause = "circular wait: " + " -> ".join(names.get(p, str(p)) for p in cycle)
            cause += " (" + "; ".join(holders[p].how for p in cycle[:-1]) + ")"
        elif w is not None:
            cause = f"{holders[root].how}, which is not locked out"
        elif not lockouts[root].known_wait:
            cause = f"{names.get(root)} is locked out; what it waits on is unknown (no status_t)"
        else:
            load = static_load_pct(config, dpus.get(root, -1))
            cause = f"DPU {dpus.get(root)} overloaded (static load {load:.1f} %): {names.get(root)} can't run"
        hold = holders[head]
        where = _where(head, Lockout(head, hold.buffer, lockouts[head].cycle), names, dpus, buffers)
        where["writer"] = names.get(hold.process, f"process {hold.process}")
        faults.append(
            Fault(
                kind="jam",
                **where,
                chain=[names.get(p, f"process {p}") for p in chain],
                detail=cause,
                static_load_pct=load,
                root_dpu=dpus.get(root),
            )
        )
    return faults


def overrun_faults(processes: list[ProcessMetrics]) -> list[Fault]:
    return [
        Fault(
            kind="overrun",
            process=p.name,
            dpu=p.dpu,
            cycle=p.first_overrun_cycle,
            count=p.overruns,
            detail=f"{p.overruns} of {p.cycles} cycles ended after the next release",
        )
        for p in processes
        if p.overruns > 0
    ]


# Ten heartbeats (5 Hz) missed in a row. The host calls a DPU lost live after 0.6 s; a
# logger starved of CPU drops messages (the newest, whoever sent them), so the log is
# judged with more margin. A DPU restarted sooner is caught by its new pid.
LOST_GAP_US = 2_000_000
# No heartbeat of any DPU logged for this long: the logger was not recording (stalled,
# starved of CPU), and that silence says nothing about any one DPU.
LOG_SILENT_US = 400_000
_IN_RUN = (skelmsg.status_t.STATE_ARMED, skelmsg.status_t.STATE_RUNNING)


def dpu_lost_faults(config: Any, records: np.ndarray, heartbeats: Sequence[Heartbeat],
                    run_id: int) -> list[Fault]:
    """A DPU is lost when its heartbeats stopped during the run: a silence of more than
    LOST_GAP_US while the log heard other DPUs, or a new daemon (pid) answering for it,
    between the run's first heartbeat and the last one of a DPU still running it (one
    clock: when they were heard). A DPU that kept heartbeating is not lost, whatever its
    timing records show (a process waiting for data that never comes stops its timing,
    not its DPU). Without heartbeat times (a live view) or heartbeats of this run (a log
    that does not record them), only a DPU with no timing record and no heartbeat is lost."""
    dpus = sorted({int(p.dpu) for p in config.processes})
    timed = set(np.unique(records["dpu"]).tolist())
    heard = [(h.heard_us, h) for h in heartbeats if h.heard_us is not None]
    run = [(t, h) for t, h in heard if h.run_id == run_id]
    if not run:
        alive = {h.dpu for h in heartbeats if h.run_id == run_id}
        return [Fault(kind="dpu_lost", dpu=d, detail="no timing records and no heartbeat in this run")
                for d in dpus if d not in timed and d not in alive]
    start = min(t for t, _ in run)
    end = max((t for t, h in run if h.state in _IN_RUN), default=start)
    silences = [(a, b) for a, b in itertools.pairwise(sorted(t for t, _ in heard)) if b - a > LOG_SILENT_US]
    faults = []
    for dpu in dpus:
        mine = [(t, h) for t, h in heard if h.dpu == dpu and start <= t <= end]
        pids = list(dict.fromkeys(h.pid for _, h in mine))
        times = [start, *(t for t, _ in mine), end]
        silent, since, gap = max((_unheard(a, b, silences), a, b - a) for a, b in itertools.pairwise(times))
        if len(pids) > 1:
            detail = f"restarted during the run (pid {pids[0]}, then {pids[-1]})"
        elif silent > LOST_GAP_US and not mine:
            detail = "no heartbeat during the run"
        elif silent > LOST_GAP_US:
            detail = f"not heard for {gap / 1e6:.2f} s from {(since - start) / 1e6:.2f} s into the run"
        elif not mine and dpu not in timed:
            detail = "no timing records and no heartbeat in this run"
        else:
            continue
        faults.append(Fault(kind="dpu_lost", dpu=dpu, detail=detail))
    return faults


def _unheard(a: int, b: int, silences: list[tuple[int, int]]) -> int:
    """How much of (a, b) the log was recording other heartbeats (not in a log silence)."""
    return (b - a) - sum(max(0, min(b, y) - max(a, x)) for x, y in silences)


def _index(config: Any) -> tuple[dict[int, str], dict[int, int], dict[int, Any]]:
    names = {p.id: p.name for p in config.processes}
    dpus = {p.id: p.dpu for p in config.processes}
    buffers = {b.id: b for b in config.buffers}
    return names, dpus, buffers


def _bname(buffers: dict[int, Any], buffer_id: int) -> str:
    desc = buffers.get(buffer_id)
    return desc.name if desc is not None else f"buffer {buffer_id}"
