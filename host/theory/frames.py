"""The cyclic executive's schedule on paper: which processes are due in which minor cycle,
what each frame demands, and when each process starts and ends relative to its release.

It mirrors dpu/cyclic.c: minor cycle j runs, in their order, the processes whose period
is a multiple r of the minor cycle with r | j (so frame 0 holds every process and is the
heaviest); a frame that ends late delays the next one, which then starts at once; releases
are on the absolute grid. A `sync: data` process waits in its turn, holding the DPU, until its
required data of the same cycle comes (`ready`: predict.py knows when its writers end); a
reader of a slower writer is paced by it (predict.py), not modelled here.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass

from ..model import Dpu, Process

# Frames simulated at most: two hyperperiods unless that is longer (mixed periods like 5 and
# 23.8 ms on one DPU make a hyperperiod of 2975 minor cycles of 200 us).
MAX_FRAMES = 20_000


@dataclass(frozen=True)
class Frame:
    """Minor cycles with the same processes due: `count` of them per hyperperiod, the first `first`."""

    first: int
    count: int
    processes: tuple[str, ...]
    demand_us: float                # Σ compute / speed of the processes due, varying ones at their mean
    minor_cycle_us: int
    wait_us: float = 0.0            # the most its data readers hold the DPU waiting, in one of them
    # ... with every varying compute at its maximum (the same as the above when none varies)
    worst_demand_us: float = 0.0
    worst_wait_us: float = 0.0

    @property
    def overflows(self) -> bool:
        """At the mean draws: it overruns its minor cycle typically, not only on long draws."""
        return self.demand_us + self.wait_us > self.minor_cycle_us

    @property
    def may_overflow(self) -> bool:
        """Only when its varying computations draw long (at most their maximum, together)."""
        return not self.overflows and self.worst_demand_us + self.worst_wait_us > self.minor_cycle_us

    def to_json(self) -> dict[str, object]:
        return {"first": self.first, "count": self.count, "processes": list(self.processes),
                "demand_us": round(self.demand_us, 1), "wait_us": round(self.wait_us, 1),
                "worst_demand_us": round(self.worst_demand_us, 1),
                "worst_wait_us": round(self.worst_wait_us, 1),
                "minor_cycle_us": self.minor_cycle_us, "overflows": self.overflows,
                "may_overflow": self.may_overflow}


@dataclass(frozen=True)
class Timing:
    """One process on its DPU's schedule, relative to its release, in us: the earliest and
    latest start of its computation and its worst response (None: it falls ever further
    behind). The earliest is with every varying compute at its minimum, the latest and the
    worst at its maximum: bounds on what any draw gives."""

    start_min_us: float
    start_max_us: float
    response_us: float | None


def compute_us(p: Process, d: Dpu) -> float:
    """What the DPU emulates per cycle: the configured compute divided by its speed (a varying
    one's mean: the figure of averages, loads and rates), and its links' costs (p.charge: the
    communicate step's, charged as a computation is emulated)."""
    return p.compute_us / d.speed + p.charge.us


def worst_us(p: Process, d: Dpu) -> float:
    """The longest a cycle computes: a varying compute's largest draw (the top of its quantile
    table, dpu/draw.c) divided by the speed, as plan.c divides the table; the most messages."""
    return p.worst_compute_us / d.speed + p.charge.in_worst_us + p.charge.out_us


def best_us(p: Process, d: Dpu) -> float:
    """The shortest a cycle computes: a varying compute's smallest draw (its table's bottom)."""
    return p.best_compute_us / d.speed + p.charge.in_best_us + p.charge.out_us


Compute = Callable[[Process, Dpu], float]


def hyperperiod(processes: list[Process], minor_us: int) -> int:
    """Minor cycles until the frames repeat."""
    return math.lcm(*(max(1, p.period_us // minor_us) for p in processes)) if processes else 1


def cyclic(d: Dpu, processes: list[Process], ready: Mapping[int, tuple[float, float]] | None = None
           ) -> tuple[tuple[Frame, ...], dict[int, Timing]]:
    """The frames of one hyperperiod, grouped by what is due, and each process's timing.
    `processes` in their order on the DPU; `ready`: per data reader, the earliest and the
    latest its required data of the same cycle comes, after its release."""
    if not processes:
        return (), {}
    ready = ready or {}
    minor = d.minor_cycle_us
    ratio = {p.id: max(1, p.period_us // minor) for p in processes}
    h = hyperperiod(processes, minor)
    # All at their maximum forever is a draw that can happen: past 100 % it falls ever behind.
    load = sum(worst_us(p, d) / p.period_us for p in processes)
    groups: dict[tuple[str, ...], list[int]] = {}
    for j in range(min(h, MAX_FRAMES)):
        due = tuple(p.name for p in processes if j % ratio[p.id] == 0)
        if due:
            groups.setdefault(due, [j, 0])[1] += 1
    late = {i: r[1] for i, r in ready.items()}
    varies = any(p.varying for p in processes)
    latest, worst_waits = _simulate(d, processes, ratio, h, late, worst_us)
    waits = _simulate(d, processes, ratio, h, late, compute_us)[1] if varies else worst_waits
    # starts only move later with the data and with longer computations before them, so the
    # earliest data and the shortest draws give the earliest starts
    earliest = (_simulate(d, processes, ratio, h, {i: r[0] for i, r in ready.items()}, best_us)[0]
                if varies or any(r[0] != r[1] for r in ready.values()) else latest)
    by_name = {p.name: p for p in processes}
    out_frames = tuple(Frame(first, count, names, sum(compute_us(by_name[n], d) for n in names), minor,
                             waits.get(names, 0.0), sum(worst_us(by_name[n], d) for n in names),
                             worst_waits.get(names, 0.0))
                       for names, (first, count) in sorted(groups.items(), key=lambda kv: kv[1][0]))
    timing = {}
    for pid, (_, start_max, end) in latest.items():
        start_min = earliest[pid][0]
        bounded = load <= 1 and math.isfinite(end)
        timing[pid] = Timing(start_min if start_min != math.inf else 0.0, start_max, end if bounded else None)
    return out_frames, timing


def _simulate(d: Dpu, processes: list[Process], ratio: dict[int, int], h: int, ready: Mapping[int, float],
              compute: Compute) -> tuple[dict[int, list[float]], dict[tuple[str, ...], float]]:
    """Per process its earliest and latest start and latest end after its release; per set of
    processes due, the most they wait for data in one minor cycle begun on time (a late one
    may wait less, its lateness then spent waiting: what it needs of its own minor cycle is
    what overflows it). COMPUTE: each cycle's computation (the mean, the largest or the
    smallest draw)."""
    minor = d.minor_cycle_us
    seen: dict[int, list[float]] = {p.id: [math.inf, 0.0, 0.0] for p in processes}
    waits: dict[tuple[str, ...], float] = {}
    t = 0.0
    frames = min(2 * h, MAX_FRAMES)
    settled = h if 2 * h <= MAX_FRAMES else 0  # measure the second hyperperiod, when there is one
    for j in range(frames):
        due = [p for p in processes if j % ratio[p.id] == 0]
        if not due:
            continue
        t = max(t, j * minor)
        on_time, waited = float(j * minor), 0.0
        for p in due:
            release = (j // ratio[p.id]) * p.period_us
            data = release + ready.get(p.id, 0.0)
            waited += max(0.0, data - on_time)
            on_time = max(on_time, data) + compute(p, d)
            start = max(t, data)
            t = start + compute(p, d)
            if j >= settled:
                s = seen[p.id]
                s[:] = min(s[0], start - release), max(s[1], start - release), max(s[2], t - release)
        if j >= settled:
            key = tuple(p.name for p in due)
            waits[key] = max(waits.get(key, 0.0), waited)
    return seen, waits
