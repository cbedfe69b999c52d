"""The cyclic executive's schedule on paper: which processes are due in which minor cycle,
what each frame demands, and when each process starts and ends relative to its release.

It mirrors dpu/executive.c: minor cycle j runs, in their order, the processes whose period
is a multiple r of the minor cycle with r | j (so frame 0 holds every process and is the
heaviest); a frame that ends late delays the next one, which then starts at once; releases
are on the absolute grid. Data waits are not modelled here (predict.py paces data readers).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from .schema import Dpu, Process

# Frames simulated at most: two hyperperiods unless that is longer (mixed periods like 5 and
# 23.8 ms on one DPU make a hyperperiod of 2975 minor cycles of 200 us).
MAX_FRAMES = 20_000


@dataclass(frozen=True)
class Frame:
    """Minor cycles with the same processes due: `count` of them per hyperperiod, the first `first`."""

    first: int
    count: int
    processes: tuple[str, ...]
    demand_us: float                # Σ compute / speed of the processes due
    minor_cycle_us: int

    @property
    def overflows(self) -> bool:
        return self.demand_us > self.minor_cycle_us

    def to_json(self) -> dict[str, object]:
        return {"first": self.first, "count": self.count, "processes": list(self.processes),
                "demand_us": round(self.demand_us, 1), "minor_cycle_us": self.minor_cycle_us,
                "overflows": self.overflows}


@dataclass(frozen=True)
class Timing:
    """One process on its DPU's schedule, relative to its release, in us: the earliest and
    latest start of its computation and its worst response (None: it falls ever further
    behind)."""

    start_min_us: float
    start_max_us: float
    response_us: float | None


def compute_us(p: Process, d: Dpu) -> float:
    """What the DPU emulates per cycle: the configured compute divided by its speed."""
    return p.compute_us / d.speed


def hyperperiod(processes: list[Process], minor_us: int) -> int:
    """Minor cycles until the frames repeat."""
    return math.lcm(*(max(1, p.period_us // minor_us) for p in processes)) if processes else 1


def cyclic(d: Dpu, processes: list[Process]) -> tuple[tuple[Frame, ...], dict[int, Timing]]:
    """The frames of one hyperperiod, grouped by what is due, and each process's timing.
    `processes` in their order on the DPU."""
    if not processes:
        return (), {}
    minor = d.minor_cycle_us
    ratio = {p.id: max(1, p.period_us // minor) for p in processes}
    h = hyperperiod(processes, minor)
    load = sum(compute_us(p, d) / p.period_us for p in processes)
    groups: dict[tuple[str, ...], list[int]] = {}
    seen: dict[int, list[float]] = {p.id: [math.inf, 0.0, 0.0] for p in processes}
    t = 0.0
    frames = min(2 * h, MAX_FRAMES)
    settled = h if 2 * h <= MAX_FRAMES else 0  # measure the second hyperperiod, when there is one
    for j in range(frames):
        due = [p for p in processes if j % ratio[p.id] == 0]
        if not due:
            continue
        if j < h:
            key = tuple(p.name for p in due)
            groups.setdefault(key, [j, 0])[1] += 1
        t = max(t, j * minor)
        for p in due:
            release = (j // ratio[p.id]) * p.period_us
            start, t = t, t + compute_us(p, d)
            if j >= settled:
                s = seen[p.id]
                s[:] = min(s[0], start - release), max(s[1], start - release), max(s[2], t - release)
    by_name = {p.name: p for p in processes}
    out_frames = tuple(Frame(first, count, names, sum(compute_us(by_name[n], d) for n in names), minor)
                       for names, (first, count) in sorted(groups.items(), key=lambda kv: kv[1][0]))
    timing = {pid: Timing(s[0] if s[0] != math.inf else 0.0, s[1], s[2] if load <= 1 else None)
              for pid, s in seen.items()}
    return out_frames, timing
