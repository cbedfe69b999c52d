"""`skel allocate`'s search: which process on which DPU, with OR-Tools CP-SAT.

The model: one boolean per (process, DPU it may run on: a DPU that reaches every link of
its buffers, the pinned one if pinned); a buffer on a `local` link keeps its writer and
readers together; each DPU's load fits its speed; on the cyclic executive the heaviest
frame (frame 0: every process is due) fits the minor cycle, which is the gcd of the
periods placed there (pairs of periods bound it; the prediction checks the rest); on the
tasking executive utilization fits (loads count a varying compute at its mean, frames and
latency at its largest draw, as the prediction verifies them), and exact response-time
analysis, which is not linear, is checked on each candidate by predict(): a DPU that fails gets a no-good cut
(those processes, from the failing one's priority up, never all on it again, while the DPUs
whose writers its data readers wait for hold what they hold) and the model is solved again.
Objectives: the worst DPU load, the worst latency of the chains
(the prediction's bound, made linear: a step's start waits for what runs before it on
its DPU), or the bytes/s of buffers read on another DPU than their writer's; each ties
broken by the next. Proven optimal when CP-SAT proves it for the model with its cuts.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace
from itertools import combinations

from ortools.sat.python import cp_model

from skeleton.analysis.errors import SkelError

from ..model import Dpu, Process, System
from ..sysfile import yamledit
from ..sysfile.system import loads
from .predict import Prediction, held_up, predict, same_cycle_waits

PPM = 1_000_000
MAX_CUTS = 200


class NoFit(SkelError):
    """No allocation fits; the message says what would."""


@dataclass(frozen=True)
class Allocation:
    dpu_of: dict[str, int]
    text: str                       # the new system file
    system: System
    prediction: Prediction
    optimal: bool                   # proven optimal (for the objective, with the cuts) or best found
    objective: str
    candidates: int                 # solutions proposed; all but the last failed the prediction
    seconds: float


def traffic_bytes_per_s(system: System) -> float:
    """Bytes/s of the buffers read on another DPU than their writer's, each writer once a
    period: the most it sends (a paced reader sends less, a process on host-sent events as
    often as the host sends, which no file says), so a bound, not the prediction's figure."""
    return sum(1e6 / system.process(b.writer).period_us * b.wire_bytes for b in system.buffers
               if any(r.dpu != system.process(b.writer).dpu for r in system.readers(b.id)))


def targets(system: System, count: int | None, speed: float | None) -> list[Dpu]:
    """The DPUs to allocate to: the file's (the first COUNT), and copies of its last one
    when COUNT is more; every one at SPEED when given."""
    dpus = list(system.dpus[:count] if count else system.dpus)
    last = system.dpus[-1]
    top = max(d.id for d in system.dpus)
    dpus += [replace(last, id=top + i + 1, cpu=None) for i in range((count or 0) - len(system.dpus))]
    return [replace(d, speed=speed) if speed else d for d in dpus]


def _explicit(system: System, section: str, key: str) -> dict[object, object]:
    """What the file itself gives (not the defaults rules.py fills in), by id."""
    return {item["id"]: item[key] for item in system.document.get(section, []) if key in item}


class _Model:
    """The CP-SAT model of one allocation problem."""

    def __init__(self, system: System, dpus: list[Dpu], pins: dict[str, int], max_load: float) -> None:
        self.system, self.dpus, self.m = system, dpus, cp_model.CpModel()
        procs = system.processes
        minor = _explicit(system, "dpus", "minor_cycle_us")
        priority = _explicit(system, "processes", "priority")
        order = _explicit(system, "processes", "order")
        # A DPU's order once moved: rules.py's, given order first among equals, then the file's
        self.rank = {p.id: (order.get(p.id, i + 1), p.id not in order, i) for i, p in enumerate(procs)}
        self.x: dict[tuple[int, int], cp_model.IntVar] = {}
        for p in procs:
            needs = {system.buffer(b).link for b in (*p.inputs, *p.outputs)}
            for d in dpus:
                if not needs <= set(d.links) or (p.name in pins and pins[p.name] != d.id):
                    continue
                if d.id in minor and d.executive == "cyclic" and p.period_us % int(minor[d.id]):  # type: ignore[call-overload]
                    continue
                if p.id in priority and d.executive != "threads":
                    continue
                self.x[p.id, d.id] = self.m.new_bool_var(f"x{p.id}_{d.id}")
            self.m.add_exactly_one(self._on(p))
        for b in system.buffers:
            if system.link(b.link).local:
                for r in system.readers(b.id):
                    for d in dpus:
                        self.m.add(self._at(b.writer, d.id) == self._at(r.id, d.id))
        for p, q in combinations(procs, 2):  # what rules.py would refuse on one DPU
            clash = (p.id in priority) != (q.id in priority) \
                or priority.get(p.id, 0) == priority.get(q.id, 1) or order.get(p.id, 0) == order.get(q.id, 1)
            for d in dpus if clash else ():
                if (p.id, d.id) in self.x and (q.id, d.id) in self.x:
                    self.m.add_bool_or([self.x[p.id, d.id].Not(), self.x[q.id, d.id].Not()])
        self.load = {}
        for d in dpus:
            # once a period, the most a process runs, however often its events (the host's) come
            share = {p.id: round(PPM * p.compute_us / p.period_us / d.speed) for p in procs}
            self.load[d.id] = sum(share[p.id] * self._at(p.id, d.id) for p in procs)
            self.m.add(self.load[d.id] <= round(PPM * max_load))
            if d.executive == "cyclic":
                self._frames(d, int(minor[d.id]) if d.id in minor else None, max_load)  # type: ignore[call-overload]
        self.worst = self.m.new_int_var(0, PPM, "worst_load")
        self.m.add_max_equality(self.worst, list(self.load.values()))

    def _on(self, p: Process) -> list[cp_model.IntVar]:
        return [v for (pid, _), v in self.x.items() if pid == p.id]

    def _at(self, pid: int, did: int) -> cp_model.LinearExprT:
        return self.x.get((pid, did), 0)

    def _demand(self, d: Dpu) -> cp_model.LinearExprT:
        # the prediction verifies frames at the largest draws (may_overflow): so does the model
        return sum(math.ceil(p.worst_compute_us / d.speed) * self._at(p.id, d.id)
                   for p in self.system.processes)

    def _frames(self, d: Dpu, minor: int | None, max_load: float) -> None:
        """Frame 0 holds every process of the DPU: its demand within the minor cycle."""
        demand = self._demand(d)
        if minor is not None:
            self.m.add(demand <= math.floor(minor * max_load))
            return
        periods = sorted({p.period_us for p in self.system.processes})
        has = {}
        for t in periods:
            has[t] = self.m.new_bool_var(f"has{d.id}_{t}")
            self.m.add_max_equality(has[t], [self._at(p.id, d.id) for p in self.system.processes
                                             if p.period_us == t] or [0])
        top = sum(math.ceil(p.worst_compute_us / d.speed) for p in self.system.processes)
        for a, b in ((a, b) for i, a in enumerate(periods) for b in periods[i:]):
            g = math.gcd(a, b)
            if g * max_load < top:
                self.m.add(demand <= math.floor(g * max_load) + top * (2 - has[a] - has[b]))

    def traffic(self) -> cp_model.LinearExprT:
        out = []
        for b in self.system.buffers:
            readers = self.system.readers(b.id)
            if not readers:
                continue
            cross = self.m.new_bool_var(f"cross{b.id}")
            for r in readers:
                for d in self.dpus:
                    self.m.add(cross >= self._at(b.writer, d.id) - self._at(r.id, d.id))
            # once a period, the most a writer sends: the rate of one on host-sent events is unknown
            rate = 1e6 / self.system.process(b.writer).period_us
            out.append(round(rate * b.wire_bytes) * cross)
        return sum(out)

    def latency(self) -> cp_model.LinearExprT:
        """The worst chain's latency bound (predict's, in us), made linear. Every writer counts
        once a period and every reader reads within its period: the objective needs a number,
        where predict() leaves a step on host-sent events unbounded and takes the worse wait
        after a writer of unknown rate."""
        worst = self.m.new_int_var(0, 10**12, "worst_chain")
        for c in self.system.chains:
            steps = [self.system.process(i) for i in c.processes]
            total: list[cp_model.LinearExprT] = []
            for i in range(1, len(steps)):
                p, before = steps[i], steps[i - 1]
                buffer = next(b for b in p.inputs if b in before.outputs)
                paced = buffer in p.required and before.period_us >= p.period_us
                total.append(self._start(p) + (0 if paced else p.period_us))
                if i < len(steps) - 1:
                    total.append(sum(math.ceil(p.worst_compute_us / d.speed) * self._at(p.id, d.id)
                                     for d in self.dpus))
            self.m.add(worst >= sum(total))
        return worst

    def _start(self, p: Process) -> cp_model.LinearExprT:
        """What runs before P on its DPU: the processes before it in the cyclic frame, the
        higher priorities on the tasking executive (one job each)."""
        out = []
        for q in self.system.processes:
            for d in self.dpus:
                first = (q.period_us, self.rank[q.id]) < (p.period_us, self.rank[p.id]) \
                    if d.executive == "threads" else self.rank[q.id] < self.rank[p.id]
                if q.id == p.id or not first or (q.id, d.id) not in self.x or (p.id, d.id) not in self.x:
                    continue
                both = self.m.new_bool_var(f"both{q.id}_{p.id}_{d.id}")
                self.m.add(both >= self.x[q.id, d.id] + self.x[p.id, d.id] - 1)
                out.append(math.ceil(q.worst_compute_us / d.speed) * both)
        return sum(out)

    def cut(self, on: dict[int, int], names: dict[int, set[str]]) -> None:
        """Never again all of NAMES (DPU -> names) on those DPUs together."""
        placed = [self.x[p.id, on[p.id]] for p in self.system.processes if p.name in names.get(on[p.id], ())]
        self.m.add(sum(placed) <= len(placed) - 1)

    def solve(self, objectives: list[cp_model.LinearExprT],
              seconds: float) -> tuple[dict[int, int], bool] | None:
        """The assignment (process id -> DPU id) optimising OBJECTIVES in turn, and whether the
        first is proven optimal; None: infeasible, or nothing found in time."""
        optimal, start = True, time.monotonic()
        solution: dict[int, int] | None = None
        # The bounds that hold each objective at its best are this call's: on the model itself
        # they outlived it, and a cut of every allocation at that best left none worse to find
        m = self.m.clone()  # the same variable indices: self.x reads its solutions
        for k, objective in enumerate(objectives):
            solver = cp_model.CpSolver()
            solver.parameters.max_time_in_seconds = max(0.1, seconds - (time.monotonic() - start))
            solver.parameters.num_workers = 2
            m.minimize(objective)
            status = solver.solve(m)
            if status not in (cp_model.OPTIMAL, cp_model.FEASIBLE):
                return None if solution is None else (solution, optimal)
            solution = {pid: did for (pid, did), v in self.x.items() if solver.boolean_value(v)}
            optimal = optimal if k else status == cp_model.OPTIMAL
            m.add(objective <= round(solver.objective_value))
            m.clear_hints()  # the next objective starts from this solution
            for v in self.x.values():
                m.add_hint(v, solver.boolean_value(v))
        return (solution, optimal) if solution is not None else None


def candidate(system: System, dpus: list[Dpu], on: dict[int, int]) -> tuple[str, System]:
    """The system file with processes on the DPUs ON says, DPUs added or sped up: its text
    (the user's, edited in place) and the system it validates to."""
    text = system.source_text
    top = yamledit.root(text)
    edits = []
    known = {d.id: d for d in system.dpus}
    for node in yamledit.value(top, "dpus").value:  # type: ignore[union-attr]
        d = int(yamledit.value(node, "id").value)  # type: ignore[union-attr]
        wanted = next((t for t in dpus if t.id == d), None)
        if wanted is not None and wanted.speed != known[d].speed:
            edits.append(yamledit.set_key(text, node, "speed", f"{wanted.speed:g}"))
    names = {link.id: link.name for link in system.links}
    for d in (d for d in dpus if d.id not in known):
        links = ("" if len(d.links) == len(system.links)
                 else f", links: [{', '.join(names[i] for i in d.links)}]")
        edits.append(yamledit.append_item(text, yamledit.value(top, "dpus"),  # type: ignore[arg-type]
                                          f"{{id: {d.id}, host: {d.host}, compute: {d.compute}, executive: "
                                          f"{d.executive}, speed: {d.speed:g}{links}}}"))
    for node in yamledit.value(top, "processes").value:  # type: ignore[union-attr]
        p = system.process(int(yamledit.value(node, "id").value))  # type: ignore[union-attr]
        if on[p.id] != p.dpu:
            edits.append(yamledit.set_key(text, node, "dpu", str(on[p.id])))
    text = yamledit.apply(text, edits)
    return text, loads(text, system.path)


def allocate(system: System, count: int | None = None, objective: str = "load",
             pins: dict[str, int] | None = None, time_limit_s: float = 10.0,
             speed: float | None = None, max_load: float = 1.0) -> Allocation:
    """The best allocation found within TIME_LIMIT_S, every DPU's load and frames within
    MAX_LOAD (a fraction: headroom for the platform's own costs); NoFit when there is none."""
    start = time.monotonic()
    dpus = targets(system, count, speed)
    found = _search(system, dpus, objective, pins or {}, time_limit_s, max_load)
    if found is None:
        raise NoFit(_what_would(system, dpus, pins or {}, time_limit_s, max_load))
    (text, new, pred), optimal, tries = found
    on = {p.name: p.dpu for p in new.processes}
    return Allocation(on, text, new, pred, optimal, objective, tries, time.monotonic() - start)


def _search(system: System, dpus: list[Dpu], objective: str, pins: dict[str, int], seconds: float,
            max_load: float = 1.0) -> tuple[tuple[str, System, Prediction], bool, int] | None:
    start = time.monotonic()
    model = _Model(system, dpus, pins, max_load)
    goals = {"load": [model.worst, model.traffic()], "traffic": [model.traffic(), model.worst],
             "latency": [model.latency(), model.worst]}[objective]
    for tries in range(1, MAX_CUTS + 1):
        left = seconds - (time.monotonic() - start)
        solved = model.solve(goals, left) if left > 0 else None
        if solved is None:
            return None
        on, optimal = solved
        text, new = candidate(system, dpus, on)
        pred = predict(new)
        failed = [d for d in pred.dpus if not d.schedulable]
        held = held_up(new)  # the order a move gives is rules.py's: only the candidate shows it
        if not failed and not held:
            return (text, new, pred), optimal, tries
        for r, _, w in held:  # a deadlock there: never the two on that DPU again
            model.cut(on, {r.dpu: {r.name, w.name}})
        for d in failed:  # the processes from the first that misses its period up (all, on cyclic)
            mine = [p for p in pred.processes if p.dpu == d.id]
            late = [p.priority for p in mine if not p.schedulable]
            names = {d.id: {p.name for p in mine if not late or p.priority >= max(late)}}
            for other in _feeding(new, d.id):
                names[other] = {p.name for p in new.processes_on(other)}
            model.cut(on, names)
    return None


def _feeding(system: System, dpu: int) -> set[int]:
    """The other DPUs whose processes may decide when DPU's data readers start: a reader waits
    for a writer of its period in each cycle (predict.same_cycle_waits), whose end follows what
    runs before it there, and so on; what fails on DPU fails only with them as they are."""
    waits = same_cycle_waits(system)
    out: set[int] = set()
    todo = [dpu]
    while todo:
        for r in system.processes_on(todo.pop()):
            for _, w in waits.get(r.id, ()):
                if w.dpu != dpu and w.dpu not in out:
                    out.add(w.dpu)
                    todo.append(w.dpu)
    return out


def _what_would(system: System, dpus: list[Dpu], pins: dict[str, int], seconds: float,
                max_load: float) -> str:
    """How many DPUs like the last one, or what speed for these, would fit."""
    n = len(dpus)
    said = f"no allocation of {len(system.processes)} processes on {n} DPUs fits"
    budget = max(1.0, seconds / 4)

    def fits(count: int, speed: float) -> bool:
        return _search(system, targets(system, count, speed), "load", pins, budget, max_load) is not None

    # a process whose largest draw is over its period is schedulable on no DPU slower than that
    slowest = max(system.processes, key=lambda p: p.worst_compute_us / p.period_us)
    least = math.ceil(100 * slowest.worst_compute_us / slowest.period_us / max_load) / 100
    speed = max(dpus[-1].speed, least)
    more = next((k for k in range(n + 1, max(n, len(system.processes)) + 1) if fits(k, speed)), None)
    fast = ""
    low, high = least, 8.0 * speed
    if fits(n, high):
        while high - low > 0.01:
            mid = (low + high) / 2
            low, high = (low, mid) if fits(n, mid) else (mid, high)
        fast = f"; {n} DPUs of speed {math.ceil(high * 100) / 100:g} would (--speed)"
    if speed > dpus[-1].speed:
        most = " at most" if slowest.varying else ""
        head = (f"{said}: {slowest.name} computes{most} {slowest.worst_compute_us:g} us every "
                f"{slowest.period_us} us, "
                f"so no DPU of speed {dpus[-1].speed:g} runs it")
        many = f"; {more} DPUs of speed {speed:g} would (--dpus {more} --speed {speed:g})" if more else ""
        return head + many + fast
    return said + (f"; {more} DPUs of speed {speed:g} would (--dpus {more})" if more else "") + fast
