"""Fatal flaws: process lockouts, pipeline jams (with the chain back to the root
cause), DPUs that run behind their schedule; and what is not the design's: stalls
of the platform, overruns, lost DPUs, buffers never delivered. Definitions only;
inputs are decoded messages, record arrays and the window's System, as in metrics.py.

What holds a locked-out process up, in order: the required input its DPU said it
waits on; the process of its DPU whose data wait held it up (the cyclic executive
is one thread: while one process waits, none of the others runs); for a
data-synchronised process, a required input whose writer is locked out too (it
cannot complete a cycle without that writer's new data). A jam is a chain of such
links between locked-out processes."""

from __future__ import annotations

from collections.abc import Collection, Iterable, Mapping
from dataclasses import dataclass, field
from typing import Any, NamedTuple

import numpy as np

import skelmsg
from skeleton.host.model import Buffer, Process, System
from skelmsg.contract import BUFFER_HEADER_BYTES, RECV_SLACK_BYTES

from ..read.messages import int_columns
from ..read.records import FLAG_LOCKOUT
from .latency import NO_OFFSETS, ClockOffsets
from .metrics import (
    ProcessMetrics,
    completed,
    cycle_end_ns,
    first_of_frame_at,
    frames,
    per_id,
    smallest_per_id,
    static_load_pct,
    window_mask,
)

# Every kind of fault, and those that say the architecture does not work (exit 3);
# `behind` only when the platform does not explain it (Fault.fatal).
KINDS = ("lockout", "jam", "behind", "skipping", "stall", "overrun", "dpu_lost", "delivery")
FATAL_KINDS = ("lockout", "jam", "behind", "skipping")


@dataclass
class Fault:
    # "lockout" | "jam" | "behind" | "skipping" | "stall" | "overrun" | "dpu_lost" | "delivery" | "code"
    kind: str
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
    host: str | None = None  # stall: the host whose DPUs stalled
    dpus: list[int] = field(default_factory=list)  # stall: the DPUs that stalled together
    at_s: float | None = None  # behind, stall, dpu_lost, lockout, jam: when, s from the run's first release
    duration_ms: float | None = None  # behind: how long; stall: how long the thread could not run
    behind_ms: float | None = None  # behind: the largest lateness of the DPU's minor cycles
    fatal: bool | None = None  # the design's flaw (exit 3), not the platform's; None: by its kind

    def __post_init__(self) -> None:
        if self.fatal is None:
            self.fatal = self.kind in ("lockout", "jam", "skipping")


@dataclass(frozen=True)
class Lockout:
    process: int
    buffer: int | None  # the required input it waits on; None when not waiting for data
    cycle: int
    known_wait: bool = True  # False when only a timing record's flag told us
    behind: int | None = None  # the process of its DPU whose data wait held it up
    release_ns: int | None = None  # the locked cycle's release, on its records' clock


@dataclass(frozen=True)
class Heartbeats:
    """status_t messages as heard, the ones without a time first, then in time order, a
    column each (a long run logs hundreds of thousands: as objects, their faults took a
    second): whether and when it was heard (one clock for every DPU: the logger's; a live
    view keeps no times), from which daemon, in which run and state."""

    known: np.ndarray  # bool: heard_us is a time
    heard_us: np.ndarray
    dpu: np.ndarray
    pid: np.ndarray
    run_id: np.ndarray
    state: np.ndarray
    mono_ns: np.ndarray  # when its DPU sent it, on the clock of its timing records


# status_t's fields Heartbeats keeps
HEARTBEAT_FIELDS = ("dpu", "pid", "run_id", "state", "mono_ns")


def heartbeats(known: np.ndarray, heard_us: np.ndarray, fields: Mapping[str, np.ndarray]) -> Heartbeats:
    """Statuses as columns (`fields`: at least HEARTBEAT_FIELDS) to Heartbeats."""
    order = np.argsort(np.where(known, heard_us, np.iinfo(np.int64).min), kind="stable")
    return Heartbeats(known=known[order], heard_us=heard_us[order],
                      **{name: fields[name][order] for name in HEARTBEAT_FIELDS})  # fmt: skip


def heartbeats_from_status(timed: Iterable[tuple[int | None, Any]]) -> Heartbeats:
    """(heard_us or None, status_t) pairs, as a live view holds them, to Heartbeats."""
    pairs = list(timed)
    known = np.fromiter((t is not None for t, _ in pairs), dtype=bool, count=len(pairs))
    heard = np.fromiter((t or 0 for t, _ in pairs), dtype=np.int64, count=len(pairs))
    columns = int_columns([s for _, s in pairs], *HEARTBEAT_FIELDS)
    return heartbeats(known, heard, dict(zip(HEARTBEAT_FIELDS, columns, strict=True)))


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
                out[int(lock.process)] = Lockout(int(lock.process), buffer, int(lock.cycle), behind=behind,
                                                 release_ns=int(lock.release_ns))
    return out


def lockouts_from_records(records: np.ndarray, known: dict[int, Lockout]) -> dict[int, Lockout]:
    """Add processes whose timing records carry FLAG_LOCKOUT but no status_t said so
    (status heartbeats lost): what they waited on is then unknown."""
    out = dict(known)
    flagged = records[(records["flags"] & FLAG_LOCKOUT) != 0]
    for proc in np.unique(flagged["process"]).tolist():
        if proc not in out:
            mine = flagged[flagged["process"] == proc]
            i = int(np.argmin(mine["cycle"]))
            out[proc] = Lockout(proc, None, int(mine["cycle"][i]), known_wait=False,
                                release_ns=int(mine["release_ns"][i]))
    return out


def lockout_at_s(lock: Lockout, system: System, dpu: int | None, origin: Mapping[int, int]) -> float | None:
    """When `lock`'s cycle passed its limit, r_k + lockout_cycles x period, in s from its
    DPU's first release (`origin`), as the definition puts it: not when the DPU found it,
    which is later by the stalls it did not count (or, before it checked at a cycle's end
    and during its computation, by up to the whole computation). None when unknown."""
    proc = system.find_process(lock.process)
    if lock.release_ns is None or lock.release_ns <= 0 or proc is None or dpu not in origin:
        return None
    limit_ns = lock.release_ns + int(system.run.lockout_cycles) * int(proc.period_us) * 1000
    return (limit_ns - origin[dpu]) / 1e9


def stalls_explain(stalled: float, loss: float) -> bool:
    """The platform's rule, for every fault it may explain: the time a DPU's thread was kept
    from running (its stalls) explains a loss of time (a lockout's window, a DPU's lateness,
    the releases a process skipped) when it accounts for half of it or more."""
    return 2 * stalled >= loss


def _tasking(system: System, dpu: int) -> bool:
    """Whether `dpu` runs the tasking executive: each of its threads records a stop of the DPU."""
    return any(d.id == dpu and d.executive == "threads" for d in system.dpus)


def writer_stall(records: np.ndarray, system: System, clock: ClockOffsets, reader: Process,
                 buffers: Iterable[int], low_ns: int, high_ns: int) -> tuple[Process, int] | None:
    """(the writer, its DPU's stalls in ns) of the one of `buffers` (read by `reader`) whose
    writer's DPU was kept from running longest while their data was due, from `low_ns` to
    `high_ns` on the reader's clock (its records' stalls, by their releases): None for none.
    A reader's own stalls are not counted against it; its writer's, on another DPU or host,
    starve it all the same."""
    low, high = clock.to_host(reader.dpu, np.array([low_ns, high_ns], dtype=np.int64)).tolist()
    best = None
    for b in buffers:
        w = _writer(system, b)
        if w is None or w.dpu == reader.dpu:
            continue
        mine = records["dpu"] == w.dpu
        at = clock.to_host(w.dpu, records["release_ns"][mine])
        due = (at >= low) & (at <= high)
        stall, process = records["stall_ns"][mine][due], records["process"][mine][due]
        # The cyclic executive's one thread records each stall once; the threads executive's
        # every thread records the same stop of its DPU: its longest-stalled thread's count.
        stalled = (max((int(stall[process == q].sum()) for q in np.unique(process).tolist()), default=0)
                   if _tasking(system, w.dpu) else int(stall.sum()))
        if best is None or stalled > best[1]:
            best = (w, stalled)
    return best


def _stall_words(w: Process, stalled: int) -> str:
    return (f"{w.name}'s DPU {w.dpu} was kept from running for {stalled / 1e6:.1f} ms meanwhile (stalls: "
            "the platform, not the design)")


def stalled_writers(lockouts: Mapping[int, Lockout], records: np.ndarray, system: System,
                    clock: ClockOffsets) -> dict[int, str]:
    """Per locked-out process waiting for data, why the platform explains it, when it does:
    its writer's DPU was kept from running (writer_stall) for half the reader's lockout window
    or more while the locked cycle's data was due (from a writer period before its release to
    its limit). A DPU stopped for 300 ms made its reader's lockout and a jam read as the
    design's flaw."""
    out = {}
    for proc, lock in lockouts.items():
        p = system.find_process(proc)
        w = None if lock.buffer is None else _writer(system, lock.buffer)
        if p is None or w is None or lock.release_ns is None:
            continue
        window = int(system.run.lockout_cycles) * p.period_us * 1000
        found = writer_stall(records, system, clock, p, [lock.buffer], lock.release_ns - w.period_us * 1000,
                             lock.release_ns + window)
        if found is not None and stalls_explain(found[1], window):
            out[proc] = _stall_words(*found)
    return out


def stall_backlog_ns(at_ns: np.ndarray, stall_ns: np.ndarray, until_ns: int, load_pct: float) -> int:
    """The stalls a DPU had not made up by `until_ns`: each stall (`stall_ns`, at `at_ns`, in time
    order) adds to a backlog that its spare time, 100 - `load_pct` % of each ns, pays off."""
    spare = max(0.0, 1.0 - load_pct / 100.0)
    backlog, last = 0.0, None
    for at, stall in zip(at_ns.tolist(), stall_ns.tolist(), strict=True):
        if at > until_ns:
            break
        if last is not None:
            backlog = max(0.0, backlog - spare * (at - last))
        backlog, last = backlog + stall, at
    if last is not None:
        backlog = max(0.0, backlog - spare * (until_ns - last))
    return int(backlog)


def stalled_dpus(lockouts: Mapping[int, Lockout], stalls: np.ndarray, system: System) -> dict[int, str]:
    """Per locked-out process its DPU could not run (not waiting for data), why the platform
    explains it, when it does: on a DPU that is not overloaded, the stalls it had not made up by
    the locked cycle's limit (stall_backlog_ns, from `stalls`: the run's records with a stall)
    hold the process off for half the lockout window or more. On the cyclic executive that is
    the backlog itself (each frame starts that late). On the tasking executive a process runs
    only in the time its priority's and the higher ones' load leave spare, so it waits the
    backlog over that spare share; every thread that ran or was ready records a stop of its DPU,
    so the longest-stalled thread's backlog is taken. SERVO's 96.5 %-loaded DPU 4 (tasking)
    makes up 3.5 % of its time: 20 ms of stalls held jacobian_update off for 330 ms, and a CI
    run's lockout of it read as the design's flaw."""
    out = {}
    for proc, lock in lockouts.items():
        p = system.find_process(proc)
        if (p is None or lock.buffer is not None or lock.behind is not None or not lock.known_wait
                or lock.release_ns is None):
            continue
        load = static_load_pct(system, p.dpu)
        if load > 100.0:
            continue
        tasking = _tasking(system, p.dpu)
        window = int(system.run.lockout_cycles) * p.period_us * 1000
        mine = stalls[stalls["dpu"] == p.dpu]
        mine = mine[np.argsort(mine["release_ns"], kind="stable")]
        series = ([mine[mine["process"] == q] for q in np.unique(mine["process"]).tolist()] if tasking
                  else [mine])
        limit = lock.release_ns + window
        backlog = max((stall_backlog_ns(s["release_ns"], s["stall_ns"], limit, load) for s in series),
                      default=0)
        level = static_load_pct(system, p.dpu, p.priority) if tasking else 0.0
        held = backlog / max(1.0 - level / 100.0, 1e-3)
        if stalls_explain(held, window):
            out[proc] = (f"its DPU {p.dpu} had {backlog / 1e6:.1f} ms of stalls still to make up by then, "
                         f"which hold it off {held / 1e6:.0f} ms (static load {load:.1f} %; stalls: the "
                         "platform, not the design)")
    return out


def lockout_faults(lockouts: dict[int, Lockout], system: System, origin: Mapping[int, int] | None = None,
                   explained: Mapping[int, str] | None = None) -> list[Fault]:
    """One fault per locked-out process, naming its cycle and, with `origin`
    (first_release_ns of the run), when that cycle's limit passed (at_s); one the platform
    `explained` (stalled_writers) says why and is not the design's flaw."""
    explained = explained or {}
    faults = []
    for proc in sorted(lockouts):
        lock = lockouts[proc]
        if lock.buffer is not None:
            detail = f"waits on {_bname(system, lock.buffer)}"
        elif lock.behind is not None:
            detail = (f"held up behind {_pname(system, lock.behind)}, which waits "
                      f"for data on the same DPU: its one thread runs neither")
        elif lock.known_wait:
            detail = "not waiting for data: its DPU cannot run it"
        else:
            detail = "flagged in the timing records (no status_t)"
        at_s = lockout_at_s(lock, system, _dpu(system, proc), origin or {})
        if at_s is not None:
            detail += f"; not completed by {at_s:.3f} s"
        if proc in explained:
            detail += f"; {explained[proc]}"
        where = _where(proc, lock, system)
        faults.append(Fault(kind="lockout", detail=detail, at_s=at_s, fatal=proc not in explained, **where))
    return faults


def _where(proc: int, lock: Lockout, system: System) -> dict[str, Any]:
    """A locked-out process's fault fields: who, where, what it waits on and from whom."""
    buf = system.find_buffer(lock.buffer) if lock.buffer is not None else None
    return {
        "process": _pname(system, proc),
        "dpu": _dpu(system, proc),
        "buffer": None if lock.buffer is None else _bname(system, lock.buffer),
        "writer": None if buf is None else _pname(system, buf.writer),
        "cycle": lock.cycle,
    }


@dataclass(frozen=True)
class _Hold:
    """What holds a locked-out process up: a process, through a buffer or not."""

    process: int | None = None
    buffer: int | None = None
    how: str = ""


def _holder(proc: int, lockouts: dict[int, Lockout], system: System) -> _Hold:
    """What holds locked-out `proc` up (see the module comment)."""
    lock = lockouts[proc]

    def name(p: int) -> str:
        return _pname(system, p)

    if lock.buffer is not None:
        buf = system.find_buffer(lock.buffer)
        if buf is None:
            return _Hold()
        how = f"{name(proc)} waits on {buf.name} from {name(buf.writer)}"
        return _Hold(int(buf.writer), lock.buffer, how)
    if lock.behind is not None:
        return _Hold(lock.behind, None,
                     f"{name(proc)} is held up behind {name(lock.behind)} on DPU {_dpu(system, proc)}")
    desc = system.find_process(proc)
    if desc is None or desc.sync != "data":
        return _Hold()
    for buffer_id in desc.inputs:
        buf = system.find_buffer(buffer_id)
        if buffer_id in desc.required and buf is not None and buf.writer in lockouts:
            how = f"{name(proc)} needs new {buf.name} from {name(buf.writer)}"
            return _Hold(int(buf.writer), int(buffer_id), how)
    return _Hold()


def jam_faults(lockouts: dict[int, Lockout], system: System, origin: Mapping[int, int] | None = None,
               explained: Mapping[int, str] | None = None) -> list[Fault]:
    """A jam: a locked-out process held up by another locked-out process.

    One fault per chain, reported from its head (a jammed process nobody jammed
    waits on) back to the root cause: a locked-out process not waiting for data (its
    DPU is overloaded), a writer that is not locked out, or a circular wait. It names
    the head's cycle, and its at_s is when that cycle's limit passed (lockout_at_s). A
    writer not locked out whose reader's lockout the platform `explained` (stalled_writers)
    is the platform's jam, not the design's, and so is one whose root its own DPU's stalls locked
    out (stalled_dpus)."""
    explained = explained or {}
    holders = {p: _holder(p, lockouts, system) for p in lockouts}

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
            cause = "circular wait: " + " -> ".join(_pname(system, p, str(p)) for p in cycle)
            cause += " (" + "; ".join(holders[p].how for p in cycle[:-1]) + ")"
        elif w is not None:
            cause = f"{holders[root].how}, which is not locked out"
            if root in explained:
                cause += f"; {explained[root]}"
        elif not lockouts[root].known_wait:
            cause = f"{_pname(system, root, None)} is locked out; what it waits on is unknown (no status_t)"
        else:
            root_dpu = _dpu(system, root)
            load = static_load_pct(system, -1 if root_dpu is None else root_dpu)
            who = _pname(system, root, None)
            cause = (f"{who} is locked out: {explained[root]}" if root in explained
                     else f"DPU {root_dpu} overloaded (static load {load:.1f} %): {who} can't run")
        hold = holders[head]
        where = _where(head, Lockout(head, hold.buffer, lockouts[head].cycle), system)
        where["writer"] = _pname(system, hold.process)
        faults.append(
            Fault(
                kind="jam",
                **where,
                chain=[_pname(system, p) for p in chain],
                detail=cause,
                static_load_pct=load,
                root_dpu=_dpu(system, root),
                at_s=lockout_at_s(lockouts[head], system, _dpu(system, head), origin or {}),
                fatal=not (root in explained and (w is None or w not in chain)),
            )
        )
    return faults


# A data-synchronised process that skips this share of its releases or more does not run
# at its rate: its DPU cannot keep it (cycle skipping sheds the load a periodic process
# would pile up as a backlog and a lockout).
SKIPPING_MIN_PCT = 10.0


def skipping_faults(processes: list[ProcessMetrics], system: System,
                    stall_ms: Mapping[int, float] | None = None) -> list[Fault]:
    """A process that skips SKIPPING_MIN_PCT of its releases or more. On a DPU that is not
    overloaded, the platform explains it when its own DPU, or the DPU of a writer it waits for,
    was kept from running (`stall_ms`, per DPU in the window) for half the time of the
    releases it skipped or more, as a lockout's writer's stalls explain it (stalled_writers):
    a SERVO run on a CPU the test's browser shared (DPU 3 stalled 1.4 s of 5.5, its writer's
    1.1 s) skipped 29 % of the Jacobian transpose's releases and read as the design's flaw."""
    stall_ms = stall_ms or {}
    faults = []
    for p in processes:
        released = p.cycles + p.releases_skipped
        if not released or 100.0 * p.releases_skipped < SKIPPING_MIN_PCT * released:
            continue
        load = static_load_pct(system, p.dpu)
        fatal = True
        if load > 100.0:
            cause = f"DPU {p.dpu} overloaded (static load {load:.1f} %)"
        else:
            cause = f"DPU {p.dpu} keeps falling a period behind"
            proc = system.find_process(p.id)
            waits = (proc.required or proc.inputs) if proc else ()
            dpus = {p.dpu, *(w.dpu for b in waits if (w := _writer(system, b)) is not None)}
            most = max(sorted(dpus), key=lambda d: stall_ms.get(d, 0.0))
            if stalls_explain(stall_ms.get(most, 0.0), p.releases_skipped * p.period_us / 1000):
                fatal = False
                cause += (f": DPU {most} was kept from running for {stall_ms[most]:.0f} ms meanwhile "
                          "(stalls: the platform, not the design)")
        faults.append(Fault(
            kind="skipping", process=p.name, dpu=p.dpu, count=p.releases_skipped, static_load_pct=load,
            fatal=fatal,
            detail=f"{p.name} skipped {p.releases_skipped} of {released} releases "
                   f"({100.0 * p.releases_skipped / released:.0f} %): it does not run at its rate; {cause}"))
    return faults


def overrun_faults(processes: list[ProcessMetrics]) -> list[Fault]:
    return [
        Fault(
            kind="overrun",
            process=p.name,
            dpu=p.dpu,
            cycle=p.first_overrun_cycle,
            count=p.overruns,
            detail=f"{p.overruns} of {p.cycles} cycles ended after the next release"
            + (f" ({p.overruns_stalled} of them by a stall: the platform)" if p.overruns_stalled else ""),
        )
        for p in processes
        if p.overruns > 0
    ]


# Ten heartbeats (5 Hz) missed in a row. The host calls a DPU lost live after 0.6 s; a
# logger starved of CPU drops messages (the newest, whoever sent them), so the log is
# judged with more margin. A DPU restarted sooner is caught by its new pid.
# A DPU is lost when its heartbeats (5 Hz) stop. Live: three missed beats (LOST_AFTER_S, the one
# timeout of host/live/listener.py). In a log: a silence of LOST_GAP_US while other DPUs were heard,
# longer because a log's gaps also hold what the logger itself dropped on a busy machine.
LOST_AFTER_S = 0.6
LOST_GAP_US = 2_000_000
# No heartbeat of any DPU logged for this long: the logger was not recording (stalled,
# starved of CPU), and that silence says nothing about any one DPU.
LOG_SILENT_US = 400_000
_IN_RUN = (skelmsg.status_t.STATE_ARMED, skelmsg.status_t.STATE_RUNNING)


def code_faults(system: System, reports: Iterable[Any]) -> list[Fault]:
    """A process whose real code failed steps (report_t's code_faults: it returned an error, said
    it wrote more than an output holds, or wrote past an output): those cycles sent none of its
    outputs."""
    out = []
    for report in reports:
        for p in report.processes:
            if p.code_faults > 0:
                name = system.process(p.process).name
                detail = (f"its step failed in {p.code_faults} cycle(s) (an error returned, an output "
                          "longer than declared, or bytes written past an output): those cycles sent no "
                          "output")
                out.append(Fault(kind="code", process=name, dpu=report.dpu, count=p.code_faults, fatal=True,
                                 detail=detail))
    return out


def dpu_lost_faults(system: System, beats: Heartbeats, run_id: int, origin: Mapping[int, int],
                    reported: Collection[int] = ()) -> list[Fault]:
    """A DPU is lost when its heartbeats stopped during the run: a silence of more than
    LOST_GAP_US while the log heard other DPUs, or a new daemon (pid) answering for it,
    between the run's first heartbeat and the last one of a DPU still running it (one
    clock: when they were heard). A DPU that kept heartbeating is not lost, whatever its
    timing records show (a process waiting for data that never comes stops its timing,
    not its DPU). Without heartbeat times (a live view) or heartbeats of this run (a log
    that does not record them), only a DPU with no timing record and no heartbeat is lost.
    A DPU that sent no end-of-run report (`reported`: the DPUs whose report_t for the run
    the log holds) is silent up to its next heartbeat after the run, or the log's last
    one: a DPU that died shortly before the run's end is lost too.
    `origin`: first_release_ns of the run's records (the DPUs with records)."""
    dpus = sorted({int(p.dpu) for p in system.processes})
    timed = set(origin)
    heard = beats.known
    run = heard & (beats.run_id == run_id)
    if not run.any():
        alive = set(beats.dpu[beats.run_id == run_id].tolist())
        return [Fault(kind="dpu_lost", dpu=d, detail="no timing records and no heartbeat in this run")
                for d in dpus if d not in timed and d not in alive]
    start = int(beats.heard_us[run].min())
    running = run & np.isin(beats.state, _IN_RUN)
    end = int(beats.heard_us[running].max()) if running.any() else start
    all_heard = np.sort(beats.heard_us[heard])
    gaps = np.flatnonzero(np.diff(all_heard) > LOG_SILENT_US)
    silences = (all_heard[gaps], all_heard[gaps + 1])
    during = heard & (beats.heard_us >= start) & (beats.heard_us <= end)
    after = heard & (beats.heard_us > end)
    faults = []
    for dpu in dpus:
        mine = during & (beats.dpu == dpu)
        pids = beats.pid[mine]
        pids = pids[np.sort(np.unique(pids, return_index=True)[1])]  # in the order first heard
        times = np.r_[start, beats.heard_us[mine], end]
        # The run ends at the last heartbeat of a DPU still running it: one killed 1.5 s
        # before that end was silent for less than LOST_GAP_US within it. But a DPU that
        # finished the run sent its report_t (which the log repair asks again for when
        # the logger missed it) and heartbeats on while idle (5 Hz); the log ends soon
        # after the others' reports. One that did neither is silent past the end, up to
        # where it was heard again (a new pid: restarted) or the log's end, and the
        # missing report leaves no doubt a dropped message would: the live rule's
        # LOST_AFTER_S of that silence makes it lost, however close to the end it died.
        next_pid = None
        tail_extended = bool(mine.any()) and dpu not in reported
        if tail_extended:
            later = after & (beats.dpu == dpu)
            if later.any():
                first_later = int(np.flatnonzero(later)[0])  # in time order: the first heard
                times[-1], next_pid = int(beats.heard_us[first_later]), int(beats.pid[first_later])
            else:
                times[-1] = max(end, int(all_heard[-1]))
        unheard = _unheard(times, silences)
        # the longest unheard stretch; on a tie, the later one (as max over (unheard, a, b - a))
        k = int(np.lexsort((np.diff(times), times[:-1], unheard))[-1])
        if tail_extended and unheard[k] <= LOST_GAP_US and unheard[-1] > LOST_AFTER_S * 1e6:
            k = len(unheard) - 1  # no silence within the run is long enough: the one at its end is
        silent, since, gap = int(unheard[k]), int(times[k]), int(times[k + 1] - times[k])
        tail_lost = tail_extended and k == len(unheard) - 1 and silent > LOST_AFTER_S * 1e6
        at_s = None
        if len(pids) > 1:
            detail = f"restarted during the run (pid {pids[0]}, then {pids[-1]})"
        elif next_pid is not None and next_pid != pids[-1]:
            detail = f"restarted at the run's end with no end-of-run report (pid {pids[-1]}, then {next_pid})"
        elif silent > LOST_GAP_US and not mine.any():
            detail = "no heartbeat during the run"
        elif silent > LOST_GAP_US or tail_lost:
            # From the run's first release, as every fault's at_s: its last heartbeat before the
            # silence, on its own clock, when it has records (the first heartbeat heard is
            # the ARMED one, half a second and more before the first release).
            sent = int(beats.mono_ns[mine][k - 1]) if k > 0 else 0
            at_s = (sent - origin[dpu]) / 1e9 if dpu in origin and sent > 0 else None
            since_s = at_s if at_s is not None else (since - start) / 1e6
            if tail_lost:  # a silence past the run's end: its length within the run
                detail = (f"not heard for {(end - since) / 1e6:.2f} s from {since_s:.2f} s into the run, "
                          "to its end and after, with no end-of-run report")
            else:
                detail = f"not heard for {gap / 1e6:.2f} s from {since_s:.2f} s into the run"
        elif not mine.any() and dpu not in timed:
            detail = "no timing records and no heartbeat in this run"
        else:
            continue
        # A crash inside real code is its DPU's loss (dpu/code.c isolates nothing): name the suspects.
        coded = [p.name for p in system.processes if p.dpu == dpu and p.code is not None]
        if coded:
            detail += f"; it runs the real code of {', '.join(coded)}: a crash there is its DPU's loss"
        faults.append(Fault(kind="dpu_lost", dpu=dpu, detail=detail, at_s=at_s))
    return faults


def _unheard(times: np.ndarray, silences: tuple[np.ndarray, np.ndarray]) -> np.ndarray:
    """For each stretch between consecutive `times`, how much of it the log was recording
    other heartbeats (not in a log silence). The silences (their starts x, ends y) are
    sorted and disjoint: the silence before any instant is a prefix sum, so this is
    O(log silences) per stretch (a long run with many short log silences made the
    pairwise sum quadratic)."""
    x, y = silences
    if not len(x):
        return np.diff(times)
    total = np.cumsum(y - x)
    last = np.searchsorted(x, times, side="right") - 1  # the last silence starting before each time
    at = np.maximum(last, 0)
    covered = np.where(last >= 0, total[at] - np.maximum(0, y[at] - times), 0)
    return np.diff(times) - np.diff(covered)


def _bname(system: System, buffer_id: int) -> str:
    desc = system.find_buffer(buffer_id)
    return desc.name if desc is not None else f"buffer {buffer_id}"


def _pname(system: System, proc: int | None, missing: str | None = "") -> str | None:
    """A process's name; `missing` when the system has none of that id ("" for "process N")."""
    desc = system.find_process(proc) if proc is not None else None
    if desc is not None:
        return desc.name
    return f"process {proc}" if missing == "" else missing


def _writer(system: System, buffer_id: int) -> Process | None:
    """The process that writes a buffer; None when the system has no such buffer or writer."""
    desc = system.find_buffer(buffer_id)
    return system.find_process(desc.writer) if desc is not None else None


def _dpu(system: System, proc: int) -> int | None:
    desc = system.find_process(proc)
    return desc.dpu if desc is not None else None


# A DPU is behind when its minor cycles start more than one minor cycle late for at
# least this many minor cycles in a row: a hiccup it catches up on is not a fault.
BEHIND_MIN_FRAMES = 20
ON_SCHEDULE_FRACTION = 10  # a frame late by less than this fraction of the worst was on schedule


def first_release_ns(records: np.ndarray) -> dict[int, int]:
    """Per DPU, its first release: the origin of a fault's `at_s`."""
    return smallest_per_id(records["dpu"], records["release_ns"])


def stall_threshold_ns(system: System, dpu: int) -> int:
    """A cycle whose thread was kept from running longer than this is a stall fault: what
    would make a minor cycle late (late_pct of it), at least 1 ms."""
    minor_us = next((d.minor_cycle_us for d in system.dpus if d.id == dpu), 0)
    return max(1_000_000, minor_us * 1000 * system.run.late_pct // 100)


# A stall fault's cycle: (DPU, where the stall may have begun, where its cycle's work ended,
# the stall), on its DPU's clock. Found per part of a run (stall_events), grouped per host
# over all of them (stall_faults): the stalls of one host's DPUs are one fault.
STALL_EVENT = np.dtype([("dpu", "i8"), ("begin_ns", "i8"), ("end_ns", "i8"), ("stall_ns", "i8")])


def stall_events(records: np.ndarray, system: System) -> np.ndarray:
    """The cycles of `records` whose DPU thread was kept from running (late wake-ups, gaps,
    preemption: timing_t.stall_ns) beyond stall_threshold_ns, as STALL_EVENT rows."""
    limit = per_id(records["dpu"], {d.id: stall_threshold_ns(system, d.id) for d in system.dpus})
    stall = records["stall_ns"]
    rows = np.flatnonzero((stall > 0) & (stall >= limit))
    hit = records[rows]
    out = np.zeros(len(rows), dtype=STALL_EVENT)
    out["dpu"], out["stall_ns"] = hit["dpu"], hit["stall_ns"]
    # the record's parts add up to where its work ended, its stalls' wall time included
    out["end_ns"] = cycle_end_ns(hit)
    before = _stall_before_start(hit, first_of_frame_at(records, rows), system)
    out["begin_ns"] = hit["start_ns"].astype(np.int64) - before
    return out


def stall_faults(events: np.ndarray, system: System, origin: Mapping[int, int]) -> list[Fault]:
    """Stall faults from the stall_events of a window (of all its parts). The stalls of one
    host's DPUs that overlap in time are one fault naming the host, when and how long: the
    platform, not the design. `origin`: first_release_ns of the whole run."""
    hosts = {d.id: d.host for d in system.dpus}
    t0 = min(origin.values(), default=0)
    # Host -> (where the stall may have begun, where its cycle's work ended, duration, DPU),
    # on the run's clock.
    events_of: dict[str, list[tuple[int, int, int, int]]] = {}
    columns = (events["dpu"].tolist(), events["stall_ns"].tolist(), events["begin_ns"].tolist(),
               events["end_ns"].tolist())
    for dpu, ns, begin, end in zip(*columns, strict=True):
        events_of.setdefault(hosts.get(dpu, "?"), []).append((begin - t0, end - t0, ns, dpu))
    faults = []
    for host, evs in sorted(events_of.items()):
        evs.sort()
        groups: list[list[tuple[int, int, int, int]]] = []
        group_end = 0
        for ev in evs:
            # The stalls of one instant: the spans where each may have been overlap.
            if groups and ev[0] <= group_end:
                groups[-1].append(ev)
                group_end = max(group_end, ev[1])
            else:
                groups.append([ev])
                group_end = ev[1]
        # A stall as long as a minor cycle of its DPUs is a fault of its own; shorter ones
        # (a busy VM has many) are one fault per host that counts them.
        minor_ns = min((d.minor_cycle_us * 1000 for d in system.dpus if d.host == host), default=0)
        short: list[int] = []
        for group in groups:
            start = min(g[0] for g in group)
            longest = max(g[2] for g in group)
            dpus = sorted({g[3] for g in group})
            if longest < minor_ns:
                short.append(longest)
                continue
            who = ", ".join(map(str, dpus))
            faults.append(Fault(
                kind="stall", host=host, dpus=dpus, dpu=dpus[0], at_s=start / 1e9, duration_ms=longest / 1e6,
                detail=f"host {host}: DPU {who} could not run for {longest / 1e6:.1f} ms at "
                       f"{start / 1e9:.2f} s (the platform, not the design)"))
        if short:
            dpus = sorted({g[3] for group in groups for g in group})
            span = (f"{min(short) / 1e6:.1f} to {max(short) / 1e6:.1f} ms" if len(short) > 1
                    else f"{short[0] / 1e6:.1f} ms")
            faults.append(Fault(
                kind="stall", host=host, dpus=dpus, dpu=dpus[0], count=len(short),
                duration_ms=max(short) / 1e6,
                detail=f"host {host}: {len(short)} shorter stall{'s' if len(short) > 1 else ''} of its "
                       f"DPUs ({span}, under a minor cycle; the platform, not the design)"))
    return faults


def _stall_before_start(hit: np.ndarray, first: np.ndarray, system: System) -> np.ndarray:
    """How much of each record's stall came before its start: a late wake-up makes the
    cycle start late by it, a stall in its computation or its publishing (kept in
    preempted_ns too) or its data wait does not, and is placed from the cycle's start. The
    record says which by its parts: what preempted_ns does not hold, as far as the cycle
    started late (start - sched). On the cyclic executive only the first record of a
    frame carries a wake-up's stall, and no more than the stalls it had not caught up on
    when it started (debt_ns, which restarts from that stall after each sleep): a record
    started late behind a stalled predecessor stalled in its own cycle. (The report had
    taken every stall to end at the start: one inside a 2 ms computation was dated its
    300 ms early.)"""
    stall = hit["stall_ns"].astype(np.int64)
    late = np.maximum(hit["start_ns"].astype(np.int64) - hit["sched_ns"].astype(np.int64), 0)
    before = np.clip(stall - hit["preempted_ns"].astype(np.int64), 0, late)
    cyclic = per_id(hit["dpu"], {d.id: d.executive == "cyclic" for d in system.dpus})
    cyclic_before = np.where(first, np.minimum(before, hit["debt_ns"].astype(np.int64)), 0)
    return np.where(cyclic == 1, cyclic_before, before)


class Behind(NamedTuple):
    """A DPU behind its schedule (behind_runs): a fault once behind_faults has asked whether a
    writer's stalls explain the data wait it is behind on (`wait`: the longest on the way, as
    (reader, from, to) on the reader's clock; None for none)."""

    dpu: int
    at_s: float
    duration_s: float
    worst_ns: int
    minor_ns: int
    cause: str
    fatal: bool
    wait: tuple[int, int, int] | None


def behind_runs(records: np.ndarray, system: System, in_window: np.ndarray | None = None,
                origin: Mapping[int, int] | None = None) -> list[Behind]:
    """A DPU whose minor cycles start more than a minor cycle late, BEHIND_MIN_FRAMES in a
    row or more: how far behind, since when, for how long, and why (a stall of the
    platform, an overload, a data wait or an overrun). `in_window`: measured(records, system),
    when the caller has it; `origin`: as stall_faults'. Each DPU's from its own records: a
    part of a run holding some DPUs finds theirs."""
    out = []
    t0 = origin if origin is not None else first_release_ns(records)
    in_window = window_mask(records, system, in_window)
    for dpu in sorted(system.dpus, key=lambda d: d.id):
        # A DPU that fell behind in its warm-up and is still behind in the window is found
        # from where it fell behind, so that its cause (a stall, say) is not cut off.
        is_mine = records["dpu"] == dpu.id
        mine, mine_measured = records[is_mine], in_window[is_mine]
        minor_ns = dpu.minor_cycle_us * 1000
        if not mine_measured.any() or minor_ns <= 0:
            continue
        minors, starts, releases = frames(mine)
        late = starts - releases
        window_minor = mine["minor"][mine_measured].min()
        for first, last in _runs(late > minor_ns, BEHIND_MIN_FRAMES):
            lo, hi = minors[first], minors[last]
            if hi < window_minor:
                continue  # behind in the warm-up only: what the warm-up is there to leave out
            span = mine[(mine["minor"] >= lo) & (mine["minor"] <= hi)]
            start = int(span["release_ns"].min())
            worst = int(late[first : last + 1].max())
            end = int(span["release_ns"].max()) + minor_ns
            worst_minor = minors[first + int(np.argmax(late[first : last + 1]))]
            t_worst = int(span["release_ns"][span["minor"] == worst_minor].min())
            # Where it was last on schedule: a DPU with little slack takes hundreds of cycles to
            # make up a stall, and one back over a minor cycle after a dip just under it owes
            # the lateness to stalls long before this run of late frames.
            on_time = np.flatnonzero(late[:first] <= worst // ON_SCHEDULE_FRACTION)
            since = int(releases[on_time[-1]]) if len(on_time) else int(releases[0])
            cause, fatal = _why_behind(mine, system, dpu.id, min(since, start - worst), start, t_worst, worst)
            out.append(Behind(dpu.id, (start - t0[dpu.id]) / 1e9, (end - start) / 1e9, worst, minor_ns, cause,
                              fatal, _longest_wait(mine, start - worst, t_worst) if fatal else None))
    return out


def behind_faults(runs: Iterable[Behind], system: System, stalls: np.ndarray,
                  clock: ClockOffsets = NO_OFFSETS) -> list[Fault]:
    """The behind_runs of a window as faults. One behind on a data wait is the platform's doing
    when the writer of that wait was on a DPU kept from running for half the lateness or more
    meanwhile (writer_stall over `stalls`: the window's records with a stall, of every DPU;
    `clock`: the DPUs' clocks)."""
    faults = []
    for b in runs:
        cause, fatal = b.cause, b.fatal
        reader = system.find_process(b.wait[0]) if b.wait is not None else None
        if b.wait is not None and reader is not None:
            found = writer_stall(stalls, system, clock, reader, reader.required, b.wait[1], b.wait[2])
            if found is not None and stalls_explain(found[1], b.worst_ns):
                cause, fatal = f"{cause}: {_stall_words(*found)}", False
        faults.append(Fault(
            kind="behind", dpu=b.dpu, at_s=b.at_s, duration_ms=b.duration_s * 1e3, behind_ms=b.worst_ns / 1e6,
            fatal=fatal,
            detail=f"DPU {b.dpu} ran up to {b.worst_ns / 1e6:.1f} ms "
                   f"({b.worst_ns / b.minor_ns:.1f} minor cycles) behind its schedule "
                   f"for {b.duration_s:.2f} s from {b.at_s:.2f} s: {cause}"))
    return faults


def _longest_wait(mine: np.ndarray, low: int, high: int) -> tuple[int, int, int] | None:
    """(the process, low, high) of the longest data wait of `mine` released from `low` to `high`."""
    way = mine[(mine["release_ns"] >= low) & (mine["release_ns"] <= high)]
    if not len(way) or int(way["blocked_ns"].max()) <= 0:
        return None
    return int(way["process"][np.argmax(way["blocked_ns"])]), low, high


def _runs(flags: np.ndarray, min_len: int) -> list[tuple[int, int]]:
    """(first, last) indices of the runs of True at least min_len long."""
    edges = np.flatnonzero(np.diff(np.r_[0, flags.astype(np.int8), 0]))
    return [(int(a), int(b) - 1) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= min_len]


def _why_behind(mine: np.ndarray, system: System, dpu: int, since: int, start: int, t_worst: int,
                worst: int) -> tuple[str, bool]:
    """Why a DPU fell behind from `start` to `t_worst` (its clock), where it was `worst` late,
    having been on schedule at `since`: (the cause in words, whether it is the design's). Time
    its thread was kept from running on the way from `since` that accounts for half the lateness
    or more is the platform's doing."""
    way = mine[(mine["release_ns"] >= since) & (mine["release_ns"] <= t_worst)]
    stalled = int(way["stall_ns"].sum())
    if stalls_explain(stalled, worst):
        return (f"its thread was kept from running for {stalled / 1e6:.1f} ms on the way "
                "(stalls, other work on its CPU: the platform, not the design)", False)
    lead = mine[(mine["release_ns"] >= start - worst) & (mine["release_ns"] <= start)]
    load = static_load_pct(system, dpu)
    if load > 100.0:
        return f"overloaded: static load {load:.1f} %", True
    if len(lead):
        blocked = lead[np.argmax(lead["blocked_ns"])]
        if blocked["blocked_ns"] * 2 >= worst:
            return (f"{_pname(system, int(blocked['process']), None)} waited "
                    f"{blocked['blocked_ns'] / 1e6:.1f} ms for its data", True)
        over = lead[np.argmin(lead["slack_ns"])]
        if over["slack_ns"] < 0:
            return (f"{_pname(system, int(over['process']), None)} overran at cycle {int(over['cycle'])} "
                    f"(computed {over['compute_ns'] / 1e6:.1f} ms) and the DPU has too little slack "
                    "to catch up", True)
    return "its cycles take longer than its minor cycle", True


# --- delivery: a buffer that never reached a reader -----------------------------------------
# What a reader's socket receive buffer must be asked for to hold one message of a buffer whole
# (LCM's recv_buf_size; the kernel grants twice that, up to net.core.rmem_max). The DPU asks for
# it (dpu/link.c, with the contract's RECV_SLACK_BYTES); `skel check` and `skel doctor` compare it
# with this host.
FRAGMENT_BYTES = 65000        # larger messages go out as several UDP datagrams (LCM fragments)
DELIVERY_MIN_SENT = 3         # a writer that published fewer gives a reader no fair chance


def recv_buf_needed(payload_bytes: int) -> int:
    """The socket receive buffer (bytes) a reader must ask for to receive one message whole."""
    return payload_bytes + BUFFER_HEADER_BYTES + RECV_SLACK_BYTES


@dataclass
class Deliveries:
    """What delivery_faults judges of a window: per process, its completed cycles (each
    published its messages, measured or not) and whether it ran; per (reader, buffer), its new
    inputs and the messages it received. The parts of a window read DPU by DPU add up (join)."""

    completed: dict[int, int] = field(default_factory=dict)
    ran: set[int] = field(default_factory=set)
    got: dict[tuple[int, int], tuple[int, int]] = field(default_factory=dict)

    @classmethod
    def of(cls, records: np.ndarray, inputs: np.ndarray, system: System, ran: set[int]) -> Deliveries:
        """The Deliveries of `records` and their `inputs`, `ran` the processes they hold."""
        done = records["process"][completed(records)]
        got = {}
        for reader in system.processes:
            if reader.id not in ran:
                continue  # no cycle, no input record
            mine = inputs["process"] == reader.id
            for buffer_id in reader.inputs:
                rows = inputs[mine & (inputs["buffer"] == buffer_id)]
                got[(reader.id, buffer_id)] = (int(np.count_nonzero(rows["new"])),
                                               int(rows["received"].sum()))
        return cls(dict(zip(*np.unique(done, return_counts=True), strict=True)), ran, got)

    @classmethod
    def join(cls, parts: Iterable[Deliveries]) -> Deliveries:
        out = cls()
        for part in parts:
            for proc, n in part.completed.items():
                out.completed[proc] = out.completed.get(proc, 0) + n
            out.ran |= part.ran
            for key, (new, received) in part.got.items():
                had = out.got.get(key, (0, 0))
                out.got[key] = (had[0] + new, had[1] + received)
        return out


def delivery_faults(system: System, seen: Deliveries,
                    lockouts: dict[int, Lockout]) -> tuple[list[Fault], dict[int, Lockout]]:
    """Buffers whose writer kept publishing but that never reached a reader: not one message
    arrived. That is the machine or the network failing (a datagram larger than the reader's
    socket receive buffer, a firewall, a route), not the design: named as a delivery failure
    (buffer, writer, reader, the likely fix), and the reader's lockout waiting on that buffer is
    taken out of the lockouts. Returns the faults and the lockouts that remain."""
    faults: list[Fault] = []
    kept = dict(lockouts)
    for reader in sorted(system.processes, key=lambda p: p.id):
        for buffer_id in reader.inputs:
            desc = system.find_buffer(buffer_id)
            if desc is None or desc.writer == reader.id:
                continue
            sent = int(seen.completed.get(desc.writer, 0))
            lock = lockouts.get(reader.id)
            waits_here = lock is not None and lock.buffer == buffer_id
            if sent < DELIVERY_MIN_SENT or not (reader.id in seen.ran or waits_here):
                continue
            new, received = seen.got.get((reader.id, buffer_id), (0, 0))
            if new or received:
                continue
            if waits_here:
                del kept[reader.id]
            faults.append(Fault(kind="delivery", process=reader.name, dpu=reader.dpu, buffer=desc.name,
                                writer=_pname(system, desc.writer), count=sent,
                                detail=_delivery_detail(desc, sent, reader.name, reader.dpu)))
    return faults, kept


def _delivery_detail(desc: Buffer, sent: int, reader: str, dpu: int | None) -> str:
    said = f"{desc.name} ({desc.bytes} bytes): {sent} published, none reached {reader}"
    if desc.bytes + BUFFER_HEADER_BYTES > FRAGMENT_BYTES:
        need = recv_buf_needed(desc.bytes)
        return (f"{said}; a message this large must fit the reader's socket receive buffer whole: on "
                f"DPU {dpu}'s host `sysctl -w net.core.rmem_max={need}` (see `skel doctor`)")
    return f"{said}; check the link between the writer's and the reader's hosts (`skel doctor`)"
