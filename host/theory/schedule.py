"""Scheduling theory for the tasking executive (`executive: threads`): one processor under
fixed-priority preemptive scheduling, as a tasking DPU runs it in compute mode sleep.

A task is `(compute, period)` in any one integer time unit (µs, ns); a task set is listed
highest priority first (rate-monotonic: shortest period first). Every task releases its
first job at 0 (the run's start, the critical instant) and one per period; a task's next
job waits for its last one to complete, as on a DPU, where a late process runs its
releases back to back.

- `response_times`: exact response-time analysis (Joseph & Pandya 1986; Audsley et al.
  1993), the worst-case response of each task when it meets its deadline (= its period).
- `ideal_schedule`: the schedule itself, simulated event by event: each job's release,
  start (when it first held the processor), completion and preemptions. The tests hold
  real DPUs to it, `make bench` measures how far a DPU's starts are from it.
- `start_ranges`: from it, each task's earliest and latest start after its release.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from fractions import Fraction

Task = tuple[int, int]  # (compute, period)
MAX_JOBS = 5_000  # jobs of one hyperperiod start_ranges simulates at most (about 25 ms)


@dataclass(frozen=True)
class Job:
    """Job `k` of task `task` (its index in the set) on the ideal schedule."""

    task: int
    k: int
    release: int
    start: int
    completion: int
    preemptions: int

    @property
    def response(self) -> int:
        return self.completion - self.release


def utilization(tasks: Sequence[Task]) -> Fraction:
    """Σ compute / period, exactly."""
    return sum((Fraction(c, t) for c, t in tasks), Fraction(0))


def response_time(tasks: Sequence[Task], i: int) -> int | None:
    """The smallest fixed point of R = C_i + Σ_{j<i} ceil(R / T_j) · C_j: task i's response
    at the critical instant; None when tasks 0..i load the processor more than fully (the
    iteration would not end). It is the worst case when R <= T_i; past its period a task's
    later jobs of the same busy period may respond later still (Lehoczky 1990)."""
    c, _ = tasks[i]
    if utilization(tasks[: i + 1]) > 1:
        return None
    r = c + sum(cj for cj, _ in tasks[:i])  # from R = C_i alone a task of C_i = 0 stops at 0
    while True:
        # A job of no computation still needs the processor at the instant R: a release of
        # a higher priority at R itself goes first (ideal_schedule), so it counts too.
        nxt = c + sum((math.ceil(r / tj) if c else r // tj + 1) * cj for cj, tj in tasks[:i])
        if nxt == r:
            return r
        r = nxt


def response_times(tasks: Sequence[Task]) -> list[int | None]:
    """`response_time` of every task, highest priority first."""
    return [response_time(tasks, i) for i in range(len(tasks))]


def _pending(tasks: Sequence[Task], nextk: list[int], active: dict[int, list[int]],
             horizon: int) -> list[int]:
    """The next release of every task without a job, before the horizon."""
    return [nextk[i] * t for i, (_, t) in enumerate(tasks) if i not in active and nextk[i] * t < horizon]


def ideal_schedule(tasks: Sequence[Task], horizon: int) -> dict[tuple[int, int], Job]:
    """Every job released before `horizon`, by (task, k), on the ideal schedule: the
    highest-priority task with a job holds the processor, a release of a higher one
    preempts it at once, nothing costs time but computing."""
    nextk = [0] * len(tasks)
    active: dict[int, list[int]] = {}  # task -> [k, release, remaining, preemptions, start]
    out: dict[tuple[int, int], Job] = {}
    t, running = 0, -1
    while True:
        for i, (c, period) in enumerate(tasks):
            if i not in active and nextk[i] * period <= t and nextk[i] * period < horizon:
                active[i] = [nextk[i], nextk[i] * period, c, 0, -1]
        releases = _pending(tasks, nextk, active, horizon)
        if not active and not releases:
            return out
        h = min(active) if active else -1
        if running >= 0 and running != h and running in active:
            active[running][3] += 1
        running = h
        until = min(releases, default=math.inf)
        if h >= 0:
            job = active[h]
            if job[4] < 0:
                job[4] = t
            until = min(until, t + job[2])
            job[2] -= int(until) - t
        t = int(until)
        if h >= 0 and active[h][2] <= 0:
            k, release, _, preemptions, start = active.pop(h)
            out[(h, k)] = Job(h, k, release, start, t, preemptions)
            nextk[h] += 1
            running = -1


def start_ranges(tasks: Sequence[Task], responses: Sequence[int | None]) -> list[tuple[int, int]] | None:
    """Each task's earliest and latest start after its release (when a job first holds the
    processor), over one hyperperiod of the ideal schedule. Exact when every task meets its
    period: then every job of a hyperperiod is done by its end, where all release together
    again, so the schedule repeats. None when one does not, or when the hyperperiod holds more
    than MAX_JOBS jobs (coprime periods): response-time analysis then bounds the start by the
    response less the compute, which a task later in a busy period may never come near (a 20
    ms task behind 1 and 2 ms ones always starts at 3 ms, bounded by 7). `responses`: the
    tasks' response_times."""
    if any(r is None or r > t for r, (_, t) in zip(responses, tasks, strict=True)):
        return None
    hyper = math.lcm(*(t for _, t in tasks))
    if sum(hyper // t for _, t in tasks) > MAX_JOBS:
        return None
    starts: list[list[int]] = [[] for _ in tasks]
    for job in ideal_schedule(tasks, hyper).values():
        starts[job.task].append(job.start - job.release)
    return [(min(mine), max(mine)) for mine in starts]
