"""The prediction: what a system will do, from its file alone, before anything runs.

predict(system) -> Prediction. Per DPU its static load and the % compute a run will
measure; on the cyclic executive every minor cycle's demand against the minor cycle
(frames.py), on the tasking executive exact response-time analysis (schedule.py); per
input buffer the new / stale / dropped share of the reader's cycles, as the analysis
counts them; the data-wait structure (a cycle of `sync: data` processes can never start,
nor can a cyclic DPU whose data reader's wait holds it from its writer there: an error; a
data reader of a slower writer is paced by it, waiting for its next value in each cycle it
runs (_paced_timings(), in its start and response); one of a writer of its own period waits, each
cycle, for that writer's end: same_cycle_waits(), in its start and all that follows); per
chain the best and worst end-to-end latency; per link its traffic. The costs a system's
links charge (model.charges()) are in each process's time per cycle (frames.compute_us) and
each DPU's predicted % communicate; the DPUs' own costs (communication, wake-up,
interference) are not in it: what a run measures beyond it is the platform's.

How often the host sends an event (`kind: host`, `skel event`) is in no file, so what follows
from the rate of a process it drives (directly, through events or data, or by taking the
time of an overloaded DPU: unknown_rates()) is None: unknown, never held against a run.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Collection
from dataclasses import asdict, dataclass
from typing import Any

from ..model import Dpu, ExpectedInput, Process, System
from . import frames
from .frames import Frame, Timing
from .schedule import response_times, start_ranges


@dataclass(frozen=True)
class Problem:
    """A flaw that makes the system unable to run: `FILE: path: problem`."""

    path: str
    problem: str


@dataclass(frozen=True)
class DpuPrediction:
    id: int
    executive: str                  # cyclic | threads
    speed: float
    minor_cycle_us: int
    hyperperiod: int                # minor cycles until the frames repeat
    load_pct: float                 # static load: Σ (compute / speed + links' costs) / period
    compute_pct: float | None       # what a run's % compute will be: at the rates processes run
    communicate_pct: float | None   # ... and its % communicate: its links' costs (the platform's not in it)
    frames: tuple[Frame, ...]       # cyclic: one hyperperiod's frames, grouped by what is due
    # even at the largest draws: cyclic: no frame overflows, nor may; tasking: every response <= period
    schedulable: bool
    lockout_ms: float | None        # overloaded: when its first process locks out, from the start

    @property
    def overflowing(self) -> tuple[Frame, ...]:
        return tuple(f for f in self.frames if f.overflows)

    @property
    def may_overflow(self) -> tuple[Frame, ...]:
        """The frames that overflow only when their varying computations draw long."""
        return tuple(f for f in self.frames if f.may_overflow)


@dataclass(frozen=True)
class ProcessPrediction:
    name: str
    dpu: int
    period_us: int
    compute_us: float               # divided by the DPU's speed; a varying one's mean
    communicate_us: float           # its links' costs per cycle, charged by its DPU (model.charges())
    priority: int                   # tasking; 0 on the cyclic executive
    rate_hz: float | None           # cycles a second it will run (paced, starved or overloaded)
    paced_by: str | None            # the writer whose data paces it (sync: data), or may: of unknown rate
    # Bounds over every draw: a varying compute at its minimum for the earliest, at its
    # maximum (its own and what runs before it) for the latest and the worst.
    start_min_us: float             # its computation's start after its release, at the earliest
    start_max_us: float             # ... and at the latest
    response_us: float | None       # worst release -> end of its work; None: unbounded

    @property
    def schedulable(self) -> bool:
        return self.response_us is not None and self.response_us <= self.period_us


@dataclass(frozen=True)
class ChainPrediction:
    """The head's output sent -> the tail's computation started (analysis/measure/chains.py)."""

    name: str
    processes: tuple[str, ...]
    best_us: float
    worst_us: float | None          # None: a step falls ever further behind
    network_us: float = 0.0         # of its latency, the mean its links' emulated delays add


@dataclass(frozen=True)
class LinkPrediction:
    name: str
    local: bool
    messages_per_s: float | None
    bytes_per_s: float | None       # on the wire: payload, LCM and UDP/IP headers
    bandwidth_mbps: float | None
    known_messages_per_s: float     # of its writers of known rate: all of it when none is unknown
    known_bytes_per_s: float
    delay_us: tuple[float, float, float] = (0.0, 0.0, 0.0)  # its emulated delay: least, mean, most
    lost_pct: float = 0.0           # the long-run share of buffers its emulation loses, or its full queue
    queue_us: float = 0.0           # the longest a message waits for its transmitter (model.Bus)

    @property
    def over(self) -> bool:
        """What the writers of known rate send is a floor of the link's traffic (the others' is
        unknown, not none), so that alone above the bandwidth is over it, whatever the host sends."""
        return self.bandwidth_mbps is not None and 8 * self.known_bytes_per_s > self.bandwidth_mbps * 1e6


@dataclass(frozen=True)
class Prediction:
    system: str
    dpus: tuple[DpuPrediction, ...]
    processes: tuple[ProcessPrediction, ...]
    inputs: tuple[ExpectedInput, ...]
    chains: tuple[ChainPrediction, ...]
    links: tuple[LinkPrediction, ...]
    errors: tuple[Problem, ...]     # the system can never run as it is (a data-wait deadlock)
    warnings: tuple[str, ...]

    def dpu(self, dpu_id: int) -> DpuPrediction:
        return next(d for d in self.dpus if d.id == dpu_id)

    def process(self, name: str) -> ProcessPrediction:
        return next(p for p in self.processes if p.name == name)

    @property
    def worst_load_pct(self) -> float:
        return max(d.load_pct for d in self.dpus)

    @property
    def schedulable(self) -> bool:
        return not self.errors and all(d.schedulable for d in self.dpus)

    def to_json(self) -> dict[str, Any]:
        out = asdict(self)
        for d, dp in zip(out["dpus"], self.dpus, strict=True):
            d["frames"] = [f.to_json() for f in dp.frames]
            d["overflowing_frames"] = [f.first for f in dp.overflowing]
        for link, lp in zip(out["links"], self.links, strict=True):
            link["over"] = lp.over
        return _rounded(out)


def _rounded(value: Any) -> Any:
    if isinstance(value, float):
        return round(value, 3) if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: _rounded(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [_rounded(v) for v in value]
    return value


@dataclass(frozen=True)
class _Schedule:
    """What a system's data waits and schedules come to: the prediction's first steps, shared
    by predict() and planned_data_us()."""

    errors: tuple[Problem, ...]
    rates: dict[int, float]
    paced: dict[int, str]  # data readers paced by a slower writer: reader -> writer's name
    unknown: set[int]  # processes of a rate host-sent events decide
    waits: dict[int, list[tuple[int, Process]]]  # same_cycle_waits
    timing: dict[int, Timing]
    frames: dict[int, tuple[Frame, ...]]  # per cyclic DPU
    ready: dict[int, tuple[float, float]]  # per waiting reader: when its data comes


def _schedule_of(system: System) -> _Schedule:
    errors, stuck = deadlocks(system)
    rates, paced = _rates(system, stuck)
    unknown = unknown_rates(system, stuck)
    waits = same_cycle_waits(system, stuck | unknown | set(paced))
    return _Schedule(errors, rates, paced, unknown, waits, *_timings(system, waits))


def predict(system: System) -> Prediction:
    plan = _schedule_of(system)
    errors, rates, paced, unknown, waits = plan.errors, plan.rates, plan.paced, plan.unknown, plan.waits
    timing, found = plan.timing, plan.frames
    dpus = []
    for d in system.dpus:
        mine = system.processes_on(d.id)
        load = sum(frames.compute_us(p, d) / p.period_us for p in mine)
        # an overloaded DPU's rates are slowed to what it can give (_serve): shares of its time
        busy = sum(p.compute_us / d.speed * rates[p.id] / 1e6 for p in mine)
        charged = sum(p.charge.us * rates[p.id] / 1e6 for p in mine)
        over = max(1.0, busy + charged)
        known = not any(p.id in unknown for p in mine)
        compute = 100 * busy / over if known else None
        communicate = 100 * charged / over if known else None
        ok = all(_meets(timing[p.id], p) for p in mine) and not any(f.overflows or f.may_overflow
                                                                    for f in found[d.id])
        dpus.append(DpuPrediction(d.id, d.executive, d.speed, d.minor_cycle_us,
                                  frames.hyperperiod(mine, d.minor_cycle_us), 100 * load,
                                  compute, communicate, found[d.id], ok, _lockout_ms(system, d, mine, load)))
    fed = {(r, w.id): _data_at(system, timing, w, b)[0] for r, ws in waits.items() for b, w in ws}
    for r, (w, data, at) in _paced_timings(system, timing, rates, paced).items():
        timing[r], fed[(r, w)] = at, data
    processes = tuple(
        ProcessPrediction(p.name, p.dpu, p.period_us, p.compute_us / system.dpu(p.dpu).speed, p.charge.us,
                          p.priority,
                          None if p.id in unknown else rates[p.id], _paced_by(system, p, paced, unknown),
                          timing[p.id].start_min_us, timing[p.id].start_max_us, timing[p.id].response_us)
        for p in system.processes)
    by_name = {p.name: p for p in processes}
    prediction = Prediction(system.name, tuple(dpus), processes, _inputs(system, rates, unknown, paced),
                            _chains(system, by_name, rates, unknown, fed), _links(system, rates, unknown),
                            errors, ())
    return Prediction(**{**prediction.__dict__, "warnings": tuple(_warnings(system, prediction, waits))})


def _paced_timings(system: System, timing: dict[int, Timing], rates: dict[int, float],
                   paced: dict[int, str]) -> dict[int, tuple[int, float, Timing]]:
    """Per data reader paced by a slower writer that runs at its own period: (that writer, the
    earliest its data comes after the release the reader runs it in, the reader's timing with
    the wait). Each cycle it waits for the writer's next value (the one it used last is not
    new), so it computes when that comes, in the cycle of the release it reached: on the
    cyclic executive the wait holds the DPU, a release whose turn comes a period late is
    skipped, and the one after runs (its turn: the release, or the end of the last cycle, plus
    what comes before it in its frame, TIMING's start); on the tasking one the latest release
    at or before the data takes it, plus its response-time analysis' wait. The frames and the
    processes after the reader are left as they were (not modelled). A writer that is itself
    paced, or of unknown rate, paces it at no grid: left out."""
    out: dict[int, tuple[int, float, Timing]] = {}
    for p in system.processes:
        w = next((system.process(system.buffer(b).writer) for b in p.required
                  if system.process(system.buffer(b).writer).name == paced.get(p.id)), None)
        if w is None or w.sync == "event" or rates[w.id] < 1e6 / w.period_us * (1 - 1e-9):
            continue
        d = system.dpu(p.dpu)
        at, compute = timing[p.id], frames.worst_us(p, d)  # its latest start and worst end
        if at.response_us is None:
            continue
        came: list[float] = []
        starts: list[float] = []
        ends: list[float] = []
        fits = sum(frames.compute_us(q, d) / q.period_us for q in system.processes_on(d.id)) <= 1
        for data in sorted(set(_data_at(system, timing, w))):
            if not math.isfinite(data):
                break
            if d.executive == "threads":
                c, s, e = _paced_tasking(p.period_us, w.period_us, data, at)
            else:
                c, s, e = _paced_cyclic(p.period_us, w.period_us, data, at.start_max_us,
                                     at.response_us - at.start_max_us - compute, compute, fits)
            came, starts, ends = came + c, starts + s, ends + e
        if starts:
            out[p.id] = (w.id, min(came), Timing(min(starts), max(starts), max(ends)))
    return out


def _pacing_releases(reader_us: int, writer_us: int) -> int:
    """Reader releases to simulate: two of the common period of reader and writer (the pattern
    repeats from there), at least 50, at most frames.MAX_FRAMES."""
    return min(frames.MAX_FRAMES, max(50, 2 * math.lcm(reader_us, writer_us) // reader_us))


def _paced_cyclic(period: int, writer: int, data: float, turn: float, after: float, compute: float,
                  fits: bool) -> tuple[list[float], list[float], list[float]]:
    """A paced reader on the cyclic executive (dpu/cyclic.c) whose writer's value m comes at
    m * WRITER + DATA: when the value each cycle takes came, its computation's start and end,
    after their release, in the second half of the releases simulated. TURN: what comes before
    it in its frame; AFTER: after it."""
    n = _pacing_releases(period, writer)
    free, last = -math.inf, -1
    came, starts, ends = [], [], []
    for k in range(n):
        release = k * period
        at = max(release, free) + turn
        if fits and at >= release + period:
            continue  # its turn a period late: the release is skipped
        newest = math.floor((at - data) / writer)
        if newest > last:
            last, start = newest, at
        else:
            last += 1
            start = max(at, last * writer + data)
        free = start + compute + after
        if k >= n // 2:
            came.append(last * writer + data - release)
            starts.append(start - release)
            ends.append(start + compute - release)
    return came, starts, ends


def _paced_tasking(period: int, writer: int, data: float, at: Timing
                   ) -> tuple[list[float], list[float], list[float]]:
    """A paced reader on the tasking executive: each value m (at m * WRITER + DATA) is taken by
    the latest release at or before it (the earlier ones skip), and from then on it waits as
    response-time analysis has it (AT: its timing with its data at its release)."""
    n = _pacing_releases(period, writer) * period // writer
    came, starts, ends = [], [], []
    for m in range(n // 2, n):
        wait = (m * writer + data) % period
        came.append(wait)
        starts.append(wait + at.start_min_us)
        starts.append(wait + at.start_max_us)
        ends.append(wait + (at.response_us or math.inf))
    return came, starts, ends


def _data_at(system: System, timing: dict[int, Timing], w: Process, buffer: int | None = None
             ) -> tuple[float, float]:
    """When W's data of a cycle comes, after its release: its earliest and latest end (inf:
    it falls ever further behind), at its shortest and longest draws, and on BUFFER's link its
    least and most emulated delay. Its publishing and the real transport are the platform's."""
    t = timing[w.id]
    least, _, most = (0.0, 0.0, 0.0) if buffer is None else system.transport_us(buffer)
    return (t.start_min_us + frames.best_us(w, system.dpu(w.dpu)) + least,
            t.response_us + most if t.response_us is not None else math.inf)


def planned_data_us(system: System) -> dict[int, float]:
    """Per `sync: data` process on a cyclic DPU that waits in each cycle for a writer of its
    period (same_cycle_waits), the latest its data comes after its release, as the prediction
    has it (0 and left out: none planned, or never in time). The host sends it to the DPU
    (process_t.ready_us), whose schedule starts the processes after the reader from there: a
    wait the design plans is on schedule, only a longer one is lateness."""
    return {r: late for r, (_, late) in _schedule_of(system).ready.items()
            if system.dpu(system.process(r).dpu).executive != "threads" and math.isfinite(late) and late > 0}


def _timings(system: System, waits: dict[int, list[tuple[int, Process]]]
             ) -> tuple[dict[int, Timing], dict[int, tuple[Frame, ...]], dict[int, tuple[float, float]]]:
    """Every process's timing and every cyclic DPU's frames, each data reader started no
    sooner than its data of the same cycle (waits): a writer's end moves its readers', and
    theirs their readers', one DPU after another, so it is done again until nothing moves.
    Also, per reader, the earliest and latest its data comes after its release."""
    ready: dict[int, tuple[float, float]] = {}
    moved: set[int] = set()
    for _ in range(len(system.processes) + 1):
        timing, found = _schedule(system, ready)
        now = {r: (max(_data_at(system, timing, w, b)[0] for b, w in ws),
                   max(_data_at(system, timing, w, b)[1] for b, w in ws)) for r, ws in waits.items()}
        if now == ready:
            return timing, found, ready
        moved, ready = {r for r in now if now[r] != ready.get(r)}, now
    # still moving: the waits go round DPUs that each hold up the next, and no cycle ever ends
    ready = {r: (e, math.inf) if r in moved else (e, late) for r, (e, late) in ready.items()}
    return (*_schedule(system, ready), ready)


def _schedule(system: System, ready: dict[int, tuple[float, float]]
              ) -> tuple[dict[int, Timing], dict[int, tuple[Frame, ...]]]:
    timing: dict[int, Timing] = {}
    found: dict[int, tuple[Frame, ...]] = {}
    for d in system.dpus:
        mine = system.processes_on(d.id)
        if d.executive == "threads":
            found[d.id] = ()
            timing.update(_tasking(d, mine, ready))
        else:
            found[d.id], cyclic = frames.cyclic(d, mine, ready)
            timing.update(cyclic)
    return timing, found


# --- rates and the data-wait structure -----------------------------------------------------

def deadlocks(system: System) -> tuple[tuple[Problem, ...], set[int]]:
    """(one error per cycle of `sync: data` processes waiting for each other and per data
    reader that holds its cyclic DPU from its writer there (held_up()), every process that
    can never start). A data process starts once every required input has a writer that
    starts; what is left never does, and each of those waits on another of them, so
    following the waits from one of them comes round to a cycle."""
    writer = {b.id: b.writer for b in system.buffers}
    stuck = {p.id for p in system.processes} - _starting(system, set())
    errors, named = [], set()
    for p in system.processes:
        if p.id not in stuck or p.id in named:
            continue
        path, at = [p.id], p.id
        while True:
            b = next(b for b in system.process(at).required if writer[b] in stuck)
            at = writer[b]
            if at in path:
                break
            path.append(at)
        loop = path[path.index(at):]
        if named & set(loop):
            named |= set(path)
            continue
        named |= set(path)
        errors.append(_cycle_problem(system, loop, writer))
    held = held_up(system)
    # a reader already in a cycle can never start anyway: one error names it
    errors += [_held_problem(system, r, b, w) for r, b, w in held if r.id not in stuck]
    # the held DPU's one thread never gets past the reader: none of its processes runs on
    # (those before it once), nor do the readers waiting for them
    blocked = {p.id for p in system.processes if p.dpu in {r.dpu for r, _, _ in held}}
    return tuple(errors), {p.id for p in system.processes} - _starting(system, blocked)


def _starting(system: System, never: set[int]) -> set[int]:
    """The processes that start, when NEVER do: a data process once each of its required
    inputs has a writer that starts."""
    writer = {b.id: b.writer for b in system.buffers}
    starts = {p.id for p in system.processes if p.sync != "data" and p.id not in never}
    grew = True
    while grew:
        more = {p.id for p in system.processes if p.id not in starts and p.id not in never
                and all(writer[b] in starts for b in p.required)}
        starts |= more
        grew = bool(more)
    return starts


def held_up(system: System) -> list[tuple[Process, int, Process]]:
    """(reader, buffer, writer): a `sync: data` reader on the cyclic executive waiting for a
    required buffer whose writer, on its DPU, cannot run before it needs the data. Its wait
    holds the DPU's one thread, so the writer never runs again: a writer after it in the
    order has written nothing in the run's first minor cycle (every process is due there),
    and one of a longer period (not an event's: it runs on no grid) nothing by its second
    cycle. A writer of its period or faster before it writes in every minor it is due."""
    out = []
    for p in system.processes:
        if p.sync != "data" or system.dpu(p.dpu).executive == "threads":
            continue
        for b in p.required:
            w = system.process(system.buffer(b).writer)
            if w.dpu == p.dpu and w.id != p.id and (
                    w.order > p.order or (w.sync != "event" and w.period_us > p.period_us)):
                out.append((p, b, w))
    return out


def _held_problem(system: System, r: Process, b: int, w: Process) -> Problem:
    buffer = system.buffer(b).name
    if w.order > r.order:
        why, when, fix = (f"{w.name} runs after it in the DPU's order", "at cycle 0",
                          f"give {w.name} an order before {r.name}")
    else:
        why, when, fix = (f"{w.name} runs every {w.period_us / 1000:g} ms to its "
                          f"{r.period_us / 1000:g} ms, so its cycle 1 finds no new {buffer}",
                          "at cycle 1", f"give {w.name} {r.name}'s period or a shorter one")
    return Problem(f"processes.{r.name}.required",
                   f"data-wait deadlock on DPU {r.dpu}'s cyclic executive: {r.name} -> {w.name} -> "
                   f"{r.name} ({r.name} waits for {buffer} from {w.name}; {why}, and {r.name}'s wait "
                   f"holds the DPU, so {w.name} never runs: both lock out {when}); {fix}, move one of them "
                   f"to another DPU or take {buffer} out of {r.name}'s `required`")


def _cycle_problem(system: System, loop: list[int], writer: dict[int, int]) -> Problem:
    names = [system.process(i).name for i in loop]
    waits = []
    for i in loop:
        p = system.process(i)
        b = next(b for b in p.required if writer[b] in loop)
        waits.append(f"{p.name} waits for {system.buffer(b).name} from {system.process(writer[b]).name}")
    return Problem(f"processes.{names[0]}.required",
                   f"data-wait deadlock: {' -> '.join([*names, names[0]])} can never start "
                   f"({'; '.join(waits)}); make one of them sync: periodic or take the buffer "
                   "out of its `required`")


def same_cycle_waits(system: System,
                     left_out: Collection[int] = ()) -> dict[int, list[tuple[int, Process]]]:
    """Per data reader, the required buffers (and their writers) it waits for in each of its
    cycles: a writer of its period is released with it (the grid is the run's), so the reader
    finds what it used last cycle until the writer's computation of this one ends. Not a
    writer before it in its cyclic frame (it has ended), nor after it there (a deadlock:
    held_up()), nor a higher priority on its tasking processor that is ready at its release (it
    holds the processor until it ends anyway), unless its link's emulated delay keeps the data
    from the reader after that end; an event writer runs on no grid. LEFT_OUT:
    readers that never start, run at an unknown rate or are paced by a slower writer."""
    out: dict[int, list[tuple[int, Process]]] = {}
    for p in sorted(system.processes, key=lambda q: -q.priority):  # a higher priority is settled first
        if p.sync != "data" or p.id in left_out:
            continue
        for b in p.required:
            w = system.process(system.buffer(b).writer)
            if w.period_us != p.period_us or w.sync == "event":
                continue
            # a link's emulated delay keeps the reader waiting after its writer ends, on one DPU too
            delayed = system.transport_us(b)[2] > 0
            cyclic = system.dpu(p.dpu).executive != "threads"
            if w.dpu == p.dpu and not delayed and (cyclic or (w.priority > p.priority and w.id not in out)):
                continue
            if w.dpu == p.dpu and cyclic and (w.order, w.id) > (p.order, p.id):
                continue  # after it in its frame: held_up()
            out.setdefault(p.id, []).append((b, w))
    return out


def nominal_rate_hz(system: System, p: Process) -> float:
    """Cycles a second P asks for: one a period; an event process at most one a period and
    one per event (a host-sent event's rate is unknown: one a period, the most it can be,
    which only the rates of the processes unknown_rates() leaves out rely on)."""
    rate = 1e6 / p.period_us
    if p.sync == "event":
        events = event_rate(system, p.event, set())
        rate = min(rate, events) if events is not None else rate
    return rate


def event_rate(system: System, name: str, seen: set[str]) -> float | None:
    """Mean events per second of NAME (None: unknown, the host sends it). A process emits once
    per cycle: every period, or for an event process once per event it can take."""
    source = next((e for e in system.events if e.name == name), None)
    if (source is not None and source.kind == "host") or name in seen:
        return None
    rate = source.rate if source is not None else 0.0
    for p in system.processes:
        if name not in p.emits:
            continue
        cycles = 1e6 / p.period_us
        if p.sync == "event":
            trigger = event_rate(system, p.event, seen | {name})
            if trigger is None:
                return None
            cycles = min(cycles, trigger)
        rate += cycles
    return rate


def unknown_rates(system: System, stuck: set[int]) -> set[int]:
    """The processes whose rate depends on how often the host sends an event: one awaiting
    such an event (event_rate() None), or an event a process of unknown rate emits; a data
    reader requiring such a process's output (it may wait for it); a process such a one may
    take time from on an overloaded DPU (_may_slow()). A DPU within 100 % slows no process."""
    writer = {b.id: b.writer for b in system.buffers}
    out: set[int] = set()
    grew = True
    while grew:
        more = {p.id for p in system.processes if p.id not in out and p.id not in stuck and (
            (p.sync == "event" and (event_rate(system, p.event, set()) is None
                                    or any(p.event in system.process(q).emits for q in out)))
            or any(writer[b] in out for b in p.required)
            or any(q.id in out for q in _may_slow(system, p)))}
        out |= more
        grew = bool(more)
    return out


def _may_slow(system: System, p: Process) -> list[Process]:
    """The processes of P's DPU that take time P would get when the DPU cannot give all
    (_serve()): on the tasking executive the higher priorities, once they and P may need
    more than the DPU; on the cyclic one all, once the DPU's static load is over 100 %."""
    d = system.dpu(p.dpu)
    mine = system.processes_on(d.id)
    if d.executive == "threads":
        mine = [q for q in mine if q.priority >= p.priority]
    if sum(frames.compute_us(q, d) / q.period_us for q in mine) <= 1:
        return []
    return [q for q in mine if q.id != p.id]


def _paced_by(system: System, p: Process, paced: dict[int, str], unknown: set[int]) -> str | None:
    """The writer pacing P, or, failing one, a required writer of unknown rate: slower than
    P it would pace it, and its wait would be in P's response."""
    if p.id in paced:
        return paced[p.id]
    writers = (system.process(system.buffer(b).writer) for b in p.required)
    return next((w.name for w in writers if w.id in unknown), None)


def _rates(system: System, stuck: set[int]) -> tuple[dict[int, float], dict[int, str]]:
    """Cycles a second each process will run, and the writer pacing each data reader. A data
    reader runs once per new sample of its slowest required input; an overloaded cyclic DPU
    runs every release back to back, so all its processes slow down alike; an overloaded
    tasking DPU serves its priorities in order and starves the lowest."""
    writer = {b.id: b.writer for b in system.buffers}
    asked = {p.id: 0.0 if p.id in stuck else nominal_rate_hz(system, p) for p in system.processes}
    rates = dict(asked)
    paced: dict[int, str] = {}
    for _ in range(2 * len(system.processes) + 2):
        wanted = dict(asked)
        for p in system.processes:
            for b in p.required:
                if rates[writer[b]] < wanted[p.id] * (1 - 1e-9):
                    wanted[p.id] = rates[writer[b]]
                    paced[p.id] = system.process(writer[b]).name
        for d in system.dpus:
            _serve(d, system.processes_on(d.id), wanted)
        if wanted == rates:
            break
        rates = wanted
    return rates, {k: v for k, v in paced.items() if rates[k] < asked[k] * (1 - 1e-9)}


def _serve(d: Dpu, mine: list[Process], rates: dict[int, float]) -> None:
    """Scales the rates the DPU's processes want to what the DPU can give them."""
    if d.executive == "threads":
        left = 1.0
        for p in sorted(mine, key=lambda p: -p.priority):
            need = frames.compute_us(p, d) * rates[p.id] / 1e6
            if need > left:
                rates[p.id] *= left / need
            left = max(0.0, left - need)
        return
    busy = sum(frames.compute_us(p, d) * rates[p.id] / 1e6 for p in mine)
    if busy > 1:
        for p in mine:
            rates[p.id] /= busy


def _tasking(d: Dpu, mine: list[Process], ready: dict[int, tuple[float, float]]) -> dict[int, Timing]:
    """Exact response-time analysis on ns (the DPU's own unit), highest priority first. A data
    reader is ready only when its data comes (READY): from then on it meets at worst the
    critical instant, and the others meet it at worst there too, so its wait only adds. Each
    computes its largest draw: the analysis bounds every job by its C, so the worst case is
    every varying job at its maximum."""
    ranked = sorted(mine, key=lambda p: -p.priority)
    tasks = [(math.ceil(frames.worst_us(p, d) * 1000), p.period_us * 1000) for p in ranked]
    # Periodic processes all released at the run's start: their starts are the ideal schedule's.
    # A data reader (waiting, paced by a slower writer or of unknown rate) or an event moves
    # releases off the grid it simulates, and a varying compute moves every start after it
    # from one hyperperiod to the next.
    periodic = all(p.sync == "periodic" and not p.varying for p in ranked)
    responses = response_times(tasks)
    starts = start_ranges(tasks, responses) if periodic else None
    out = {}
    for i, (p, (c, _), r) in enumerate(zip(ranked, tasks, responses, strict=True)):
        early, late = ready.get(p.id, (0.0, 0.0))
        if starts is not None and r is not None:
            out[p.id] = Timing(starts[i][0] / 1000, starts[i][1] / 1000, r / 1000)
        else:
            out[p.id] = (Timing(early, late + (r - c) / 1000, late + r / 1000)
                         if r is not None and math.isfinite(late) else Timing(early, math.inf, None))
    return out


def _meets(t: Timing, p: Process) -> bool:
    return t.response_us is not None and t.response_us <= p.period_us


def _lockout_ms(system: System, d: Dpu, mine: list[Process], load: float) -> float | None:
    """When an overloaded DPU's first process locks out, in ms from the run's start.

    The cyclic executive runs its frames back to back from the start, so the work released
    before r is done by about load x r, and a process's cycle released at r completes about
    load x r + its part of frame 0 (its own compute and that of those before it in the
    order). Its cycle k locks out at r_k + lockout_cycles x period when not completed by
    then: the first k with load x r_k + part >= r_k + L x T (a cycle that would end just
    at its limit ends after it: the executive's own cost adds up over the cycles). A
    computation longer than the window locks out cycle 0, at L x T. The tasking executive
    lets the lowest priorities absorb the overload: there it falls behind by (1 - 1/load)
    of the time (it does a second's work in `load` seconds) and a process locks out once
    lockout_cycles of its periods behind."""
    if load <= 1 or not mine:
        return None
    window = {p.id: system.run.lockout_cycles * p.period_us for p in mine}
    if d.executive == "threads":
        return min(window.values()) / (1 - 1 / load) / 1000
    first, part = math.inf, 0.0
    for p in mine:  # in their order on the DPU, as frame 0 runs them
        part += frames.compute_us(p, d)
        # (rounding: 1.2 - 1 is 0.19999999999999996, and an exact k must not become k + 1)
        k = max(0, math.ceil((window[p.id] - part) / ((load - 1) * p.period_us) - 1e-9))
        first = min(first, k * p.period_us + window[p.id])
    return first / 1000


# --- buffers, chains, links ----------------------------------------------------------------

def _inputs(system: System, rates: dict[int, float], unknown: set[int],
            paced: dict[int, str]) -> tuple[ExpectedInput, ...]:
    """A share is known when every rate the two may run at gives it: an unknown rate is any
    from 0 up to the one P asks for (nominal_rate_hz), so a writer at least that fast gives
    every cycle of an unknown reader new data, and one at most that slow drops nothing.
    Dropped counts sequences: a paced writer (PACED) numbers every release, the ones it skips
    too (its readers see those as dropped, unpublished), so it drops its release rate less
    the new data it gives (a reader of a 5 ms writer paced to 50 Hz, at 100 Hz: 2 - 0.5)."""
    def span(p: Process) -> tuple[float, float]:
        return (0.0, nominal_rate_hz(system, p)) if p.id in unknown else (rates[p.id], rates[p.id])

    out = []
    for p in system.processes:
        for b in map(system.buffer, p.inputs):
            w = system.process(b.writer)
            (low, high), (slow, fast) = span(w), span(p)
            least = low / fast if fast > 0 else 0.0  # a reader that never runs finds nothing
            most = high / slow if slow > 0 else (math.inf if high > 0 and fast > 0 else 0.0)
            new = min(1.0, least) if min(1.0, least) == min(1.0, most) else None
            stale = None if new is None else 1 - new
            dropped = max(0.0, least - 1) if max(0.0, least - 1) == max(0.0, most - 1) else None
            if w.id in paced and new is not None and p.id not in unknown and rates[p.id] > 0:
                dropped = 1e6 / w.period_us / rates[p.id] - new
            out.append(ExpectedInput(p.name, b.name, w.name, new, stale, dropped,
                                     system.transport_us(b.id)[1], system.lost_pct(b.link)))
    return tuple(out)


def _chains(system: System, by_name: dict[str, ProcessPrediction], rates: dict[int, float],
            unknown: set[int], fed: dict[tuple[int, int], float]) -> tuple[ChainPrediction, ...]:
    """Per step, the value waits for the reader's next read: at best none; at worst a whole
    reader period plus the spread of its start, or, for a reader paced by that very buffer
    (it waits for each value), its latest start, less the writer's earliest end when it waits
    for the value of its own cycle (FED: (reader, writer) -> that end); a reader of unknown
    rate that runs on events reads when the next comes, which nothing bounds. A step in the
    middle then computes (at best its compute, at worst up to its response). A link's emulated
    delay (Link.delay_us) comes before the read: its least at best, its most at worst."""
    out = []
    for c in system.chains:
        steps = [system.process(i) for i in c.processes]
        best, worst, network = 0.0, 0.0, 0.0
        for i, (before, p) in enumerate(itertools.pairwise(steps), start=1):
            at = by_name[p.name]
            buffer = next(b for b in p.inputs if b in before.outputs)
            # its link's emulated delay: the value is seen that much later, then waits for the read
            least, mean, most = system.transport_us(buffer)
            best, network = best + least, network + mean
            fastest = nominal_rate_hz(system, before) if before.id in unknown else rates[before.id]
            data_paced = buffer in p.required and fastest <= 1e6 / p.period_us * (1 + 1e-9)
            wait = at.start_max_us if data_paced else p.period_us + at.start_max_us - at.start_min_us
            wait += most
            if data_paced and (p.id, before.id) in fed:  # FED holds the least delay, its start the most
                wait = max(0.0, at.start_max_us - fed[(p.id, before.id)]) + least
            if buffer in p.required and before.id in unknown:  # below its fastest, the writer may pace P
                wait = max(wait, at.start_max_us)
            worst += math.inf if p.sync == "event" and p.id in unknown else wait
            if i < len(steps) - 1:
                best += frames.best_us(p, system.dpu(p.dpu))
                worst += (at.response_us or math.inf) - at.start_max_us
        out.append(ChainPrediction(c.name, tuple(s.name for s in steps), best,
                                   worst if math.isfinite(worst) else None, network))
    return tuple(out)


def _links(system: System, rates: dict[int, float], unknown: set[int]) -> tuple[LinkPrediction, ...]:
    out = []
    for link in system.links:
        mine = [b for b in system.buffers if b.link == link.id]
        known = [b for b in mine if b.writer not in unknown]
        messages = sum(rates[b.writer] for b in known)
        size = sum(rates[b.writer] * link.message_bytes(b) for b in known)
        whole = len(known) == len(mine)
        bus = system.buses.get(link.id)
        out.append(LinkPrediction(link.name, link.local, messages if whole else None, size if whole else None,
                                  link.bandwidth_mbps, messages, size, link.delay_us,
                                  system.lost_pct(link.id),
                                  bus.most_wait_us if bus is not None else 0.0))
    return tuple(out)


def _waits_said(system: System, pred: Prediction, waits: dict[int, list[tuple[int, Process]]],
                names: set[str]) -> str:
    """What the data readers among NAMES wait for, each cycle: what makes a frame or a response
    longer than its computations."""
    said = []
    for r, ws in waits.items():
        reader = system.process(r)
        if reader.name not in names:
            continue
        for b, w in ws:
            end = pred.process(w.name).response_us
            when = f"at worst {end / 1000:g} ms after their release" if end is not None else "never in time"
            said.append(f"{reader.name} waits for {system.buffer(b).name} until {w.name} (DPU {w.dpu}) "
                        f"ends, {when}")
    return "; ".join(said)


def _warnings(system: System, pred: Prediction, waits: dict[int, list[tuple[int, Process]]]) -> list[str]:
    out: list[str] = []
    for d in pred.dpus:
        frames_said = "; ".join(
            f"minor cycle {f.first} ({f.count} of every {d.hyperperiod}) demands "
            + (f"{(f.demand_us + f.wait_us) / 1000:g} ms ({', '.join(f.processes)})"
               + (f", {f.wait_us / 1000:g} ms of it waiting for data" if f.wait_us > 0 else "")
               if math.isfinite(f.wait_us) else
               f"{f.demand_us / 1000:g} ms ({', '.join(f.processes)}) after data that never comes")
            for f in d.overflowing[:3])
        frames_said += "; ..." if len(d.overflowing) > 3 else ""
        waited = _waits_said(system, pred, waits, {n for f in d.overflowing if f.wait_us > 0
                                                   for n in f.processes})
        frames_said += f": {waited}" if waited else ""
        if d.lockout_ms is not None:
            # A process on host-sent events is counted once a period, the most it can run: with
            # fewer events the DPU may keep up, so the verdict is a bound (compute_pct unknown).
            most = " (host-sent events at their most, one a period)" if d.compute_pct is None else ""
            out.append(f"DPU {d.id}: static load {d.load_pct:.1f} % exceeds 100 %{most}: it will overrun "
                       f"every cycle and fall {100 * (1 - 100 / d.load_pct):.0f} % of the time behind; "
                       f"lockout predicted about {d.lockout_ms:.0f} ms into the run"
                       + (f"; {frames_said}" if frames_said else ""))
        elif frames_said:
            out.append(f"DPU {d.id}: frames overflow the {d.minor_cycle_us / 1000:g} ms minor cycle: "
                       f"{frames_said}")
        if d.may_overflow and d.lockout_ms is None:
            # Not a certainty: their draws are independent, so it is as rare as long draws together.
            out.append(f"DPU {d.id}: frames may overflow the {d.minor_cycle_us / 1000:g} ms minor cycle "
                       "when their varying computations draw long: " + "; ".join(
                           f"minor cycle {f.first} ({f.count} of every {d.hyperperiod}) demands "
                           f"{(f.demand_us + f.wait_us) / 1000:g} ms on average, up to "
                           f"{(f.worst_demand_us + f.worst_wait_us) / 1000:g} ms at their largest draws "
                           f"({', '.join(f.processes)})" for f in d.may_overflow[:3])
                       + ("; ..." if len(d.may_overflow) > 3 else ""))
        for p in pred.processes:
            if p.dpu == d.id and d.executive == "threads" and not p.schedulable:
                resp = f"{p.response_us / 1000:g} ms" if p.response_us is not None else "unbounded"
                waited = _waits_said(system, pred, waits, {p.name})
                # its response is the worst over the draws: long ones of its own or a higher priority's
                drawn = any(q.varying for q in system.processes_on(d.id) if q.priority >= p.priority)
                out.append(f"DPU {d.id}: {p.name} (priority {p.priority}) "
                           + ("may miss its deadline when varying computations draw long: worst "
                              if drawn else "misses its deadline: worst ")
                           + f"response {resp} > period {p.period_us / 1000:g} ms"
                           + (f" ({waited})" if waited else ""))
    for p in pred.processes:
        if p.paced_by is None:
            continue
        ask = 1e6 / p.period_us
        if p.rate_hz is None:
            out.append(f"{p.name} (sync: data, {ask:g} Hz) waits for {p.paced_by}: how often it runs depends "
                       f"on events the host sends, and it locks out if {p.paced_by} writes less often than "
                       f"once every lockout_cycles ({system.run.lockout_cycles}) of its periods")
            continue
        line = (f"{p.name} (sync: data, {ask:g} Hz) is paced by {p.paced_by}: it will run at "
                f"{p.rate_hz:.3g} Hz")
        slowest = 1e6 / p.rate_hz if p.rate_hz > 0 else math.inf
        if slowest >= system.run.lockout_cycles * p.period_us:
            line += (f", one cycle per {slowest / 1000:g} ms, at least lockout_cycles "
                     f"({system.run.lockout_cycles}) periods: it will lock out")
        out.append(line)
    for link in pred.links:
        if link.over:
            least, tail = (("", "") if link.bytes_per_s is not None else
                           ("at least ", ", its writers of known rate: those on host-sent events add theirs"))
            out.append(f"link {link.name}: {least}{8 * link.known_bytes_per_s / 1e6:.3g} Mbit/s of buffers "
                       f"({link.known_messages_per_s:.0f} messages/s{tail}) exceeds its bandwidth_mbps "
                       f"{link.bandwidth_mbps:g}")
    for k in system.links:
        bus = system.buses.get(k.id)
        if bus is not None and bus.saturated:
            out.append(f"link {k.name}: its transmit queue fills: each message waits about queue_us "
                       f"({k.queue_us / 1000:g} ms), and {bus.dropped_pct:.3g} % are dropped")
        elif bus is not None and bus.most_wait_us >= k.queue_us:
            out.append(f"link {k.name}: when its writers send at once, a message waits its whole queue_us "
                       f"({k.queue_us / 1000:g} ms): some may be dropped")
    return out
