"""A live switch of a tasking DPU (`executive: threads`, compute mode sleep): a COMMIT during a
run takes effect at one point of the grid, as on the cyclic executive, and the jobs in progress
there carry over (dpu/swap.c). The test plays the host (stage a generation, COMMIT it with an
instant) and judges the switch from the timing records the DPU publishes.

The set: p1 (T = 10 ms, C = 3 ms) and p2 (T = 12 ms, C = 3 ms), a 2 ms grid and a 60 ms
hyperperiod. The COMMIT's instant is put 1 ms after a hyperperiod's start, so the switch falls on
its 2 ms point, where p1's job of that hyperperiod has 1 ms left to compute and p2's waits
for the processor: both jobs are carried over, every time.
"""

from __future__ import annotations

import threading
import time
from collections import defaultdict
from dataclasses import dataclass
from pathlib import Path

import lcm
from conftest import DpuFarm
from test_dpu_reconfig import _stage

import skelmsg
from skeleton.host.control import Control
from skeleton.host.schedule import ideal_schedule
from skeleton.host.system import System, load
from skeleton.host.wire import config_message
from skelmsg.contract import TIMING_CHANNEL

MS = 1_000_000
HYPER_NS = 60 * MS
STALL_NS = 100_000
FLAGS = skelmsg.timing_t
SYSTEM = """\
system: tasking-switch
links: [{{name: bus, url: "{url}"}}]
dpus: [{{id: 1, executive: threads}}]
processes:
  - {{id: 1, name: p1, dpu: 1, period_us: 10000, compute_us: 3000}}
  - {{id: 2, name: p2, dpu: 1, period_us: 12000, compute_us: 3000}}
run: {{warmup_cycles: 2, lockout_cycles: 20, stop_on: []}}
"""


@dataclass(frozen=True)
class Rec:
    generation: int
    process: int
    cycle: int
    release_ns: int
    start_ns: int
    asked_ns: int
    compute_ns: int
    end_ns: int
    preemptions: int
    stall_ns: int
    flags: int


class Tap:
    """Every timing record of one run of DPU 1, decoded from SKEL_TIMING."""

    def __init__(self, url: str, run_id: int) -> None:
        self.run_id = run_id
        self.records: list[Rec] = []
        self._lock = threading.Lock()
        self._lcm = lcm.LCM(url)
        self._lcm.subscribe(TIMING_CHANNEL, self._handle).set_queue_capacity(0)
        self._running = True
        self._thread = threading.Thread(target=self._drain, daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        while self._running:
            self._lcm.handle_timeout(50)

    def _handle(self, _channel: str, data: bytes) -> None:
        m = skelmsg.timing_t.decode(data)
        if m.run_id != self.run_id:
            return
        period = {1: 10 * MS, 2: 12 * MS, 3: 20 * MS}
        with self._lock:
            for i in range(m.n):
                end = m.release_ns[i] + period.get(m.process[i], 0) - m.slack_ns[i]
                self.records.append(Rec(m.generation, m.process[i], m.cycle[i], m.release_ns[i],
                                        m.start_ns[i], m.asked_ns[i], m.compute_ns[i], end,
                                        m.preemptions[i], m.stall_ns[i], m.flags[i]))

    def close(self) -> list[Rec]:
        self._running = False
        self._thread.join(timeout=1.0)
        with self._lock:
            return sorted(self.records, key=lambda r: (r.release_ns, r.process))


def _system(tmp_path: Path, url: str, *overrides: str) -> System:
    path = tmp_path / "tasking-switch.yaml"
    path.write_text(SYSTEM.format(url=url))
    return load(path, list(overrides)).with_url(url)


@dataclass
class Switched:
    g: int
    t0: int             # the run's first release (every process's k = 0)
    at: int             # the grid point the switch must fall on: t0 + n x 60 ms + 2 ms
    records: list[Rec]
    report: skelmsg.report_t
    status: skelmsg.status_t


def _switch(dpus: DpuFarm, url: str, run_id: int, before: System, after: System,
            duration_s: float = 2.5) -> Switched:
    """DPU 1 runs `before`; `after` is committed for 1 ms past a hyperperiod's start, 0.8 s in."""
    dpus.start(1)
    control = Control(url)
    tap = Tap(url, run_id)
    try:
        assert control.wait_heard([1], 5.0) == []
        g = control.next_generation()
        pushed = control.push(config_message(before, g, 0, committed=False), [1])
        assert pushed.ok and pushed.applied == [1], pushed
        start_utc = time.time_ns() + 200 * MS
        control.start(g, run_id, start_utc, int(duration_s * 1e9))
        _stage(control, config_message(after, g + 1, run_id, committed=False), [1])
        n = 14  # 840 ms after the start: well after the staging
        at_utc = start_utc + n * HYPER_NS + 1 * MS
        assert time.time_ns() < at_utc - 100 * MS, "staging took too long"
        control.command(skelmsg.command_t.COMMIT, generation=g + 1, at_utc_ns=at_utc)
        assert control.wait_for(lambda: (1, run_id) in control.reports, duration_s + 5)
        assert control.wait_for(lambda: control.dpus[1].status.state == skelmsg.status_t.STATE_READY, 2.0)
    finally:
        records = tap.close()
        control.close()
    t0 = min(r.release_ns for r in records)
    return Switched(g, t0, t0 + n * HYPER_NS + 2 * MS, records, control.reports[(1, run_id)],
                    control.dpus[1].status)


def _contiguous(records: list[Rec], process: int) -> list[Rec]:
    mine = sorted((r for r in records if r.process == process), key=lambda r: r.cycle)
    cycles = [r.cycle for r in mine]
    assert cycles == list(range(cycles[0], cycles[0] + len(cycles))), (process, cycles)  # none lost or twice
    return mine


def _clean(done: Switched) -> None:
    """The run ended clean: no lockout, no cut-short cycle, the report of the new generation."""
    bad = [r for r in done.records if r.flags & (FLAGS.FLAG_LOCKOUT | FLAGS.FLAG_SKIPPED)]
    assert not bad, bad
    assert done.report.generation == done.g + 1
    assert not any(p.locked_out for p in done.report.processes)
    assert done.status.generation == done.g + 1 and not done.status.reject_reason


def _switch_instant(done: Switched) -> int:
    """Where the records say the switch was: every job released before it is the old
    generation's, every one at or after it the new one's."""
    first_new = min(r.release_ns for r in done.records if r.generation == done.g + 1)
    assert {r.generation for r in done.records} == {done.g, done.g + 1}
    assert all((r.generation == done.g + 1) == (r.release_ns >= first_new) for r in done.records)
    return first_new


def test_live_compute_change_of_a_tasking_dpu_carries_its_jobs_over(dpus: DpuFarm, url: str,
                                                                    tmp_path: Path) -> None:
    before = _system(tmp_path, url)
    after = _system(tmp_path, url, "process.p1.compute_us=4000")
    done = _switch(dpus, url, 6161, before, after)
    _clean(done)
    # p2's release at the switch point's hyperperiod start is the last of the old generation;
    # the first of the new is p1's at t0 + n x 60 + 10 ms (no release falls on the 2 ms point).
    assert _switch_instant(done) == done.at + 8 * MS
    p1 = _contiguous(done.records, 1)
    _contiguous(done.records, 2)
    # The job p1 was computing at the switch is carried: it computes what it asked, 3 ms,
    # once, without being preempted (it still has the highest priority).
    carried = next(r for r in p1 if r.release_ns == done.at - 2 * MS)
    assert carried.generation == done.g and carried.asked_ns == 3 * MS, carried
    assert 2.99 * MS <= carried.compute_ns < 3.3 * MS and carried.preemptions == 0, carried
    assert carried.end_ns - carried.release_ns < 3.5 * MS, carried
    # From the next job on p1 computes the new 4 ms; before, the old 3 ms.
    assert all(r.asked_ns == 3 * MS for r in p1 if r.release_ns < done.at)
    new = [r for r in p1 if r.release_ns > done.at]
    assert len(new) > 100 and all(r.asked_ns == 4 * MS and r.compute_ns >= 3.99 * MS for r in new)
    # p2's carried job waited behind p1's and ran next, as the ideal schedule has it.
    p2_carried = next(r for r in done.records if r.process == 2 and r.release_ns == done.at - 2 * MS)
    assert p2_carried.generation == done.g and abs(p2_carried.start_ns - (done.at + 1 * MS)) < 0.3 * MS
    # The report's sums cover the whole run, over both generations.
    by_id = {p.process: p for p in done.report.processes}
    assert by_id[1].cycles > len(new) and by_id[1].cycles >= len(p1) - 10


def _preempted(records: list[Rec], process: int, lo: int, hi: int) -> list[int]:
    """Preemptions of each job of `process` released in [lo, hi), unstalled."""
    return [r.preemptions for r in records
            if r.process == process and lo <= r.release_ns < hi and r.stall_ns <= STALL_NS]


def test_live_priority_swap_changes_which_process_is_preempted(dpus: DpuFarm, url: str,
                                                               tmp_path: Path) -> None:
    before = _system(tmp_path, url)  # rate-monotonic: p1 first
    after = _system(tmp_path, url, "process.p1.priority=10", "process.p2.priority=20")
    done = _switch(dpus, url, 6262, before, after)
    _clean(done)
    _contiguous(done.records, 1)
    _contiguous(done.records, 2)
    # p1's job in progress at the switch is preempted by p2's, which has the processor first now.
    carried = next(r for r in done.records if r.process == 1 and r.release_ns == done.at - 2 * MS)
    assert carried.preemptions == 1 and carried.asked_ns == 3 * MS, carried
    assert 2.99 * MS <= carried.compute_ns < 3.3 * MS, carried
    # Before: p2 is preempted by p1's releases, p1 never; after (a hyperperiod later, once the
    # carried jobs are done), the other way round, as the ideal schedules have it.
    for tasks, first in (([(3, 10), (3, 12)], 1), ([(3, 12), (3, 10)], 2)):
        jobs = ideal_schedule(tasks, 60).values()
        assert {j.task for j in jobs if j.preemptions} == {1}, (first, jobs)
    end = max(r.release_ns for r in done.records)
    early, late = (done.t0 + 2 * HYPER_NS, done.at - 2 * MS), (done.at + HYPER_NS, end - HYPER_NS)
    assert set(_preempted(done.records, 1, *early)) == {0}
    assert max(_preempted(done.records, 2, *early)) == 1
    assert set(_preempted(done.records, 2, *late)) == {0}
    assert max(_preempted(done.records, 1, *late)) == 1


def test_live_switch_adds_and_removes_processes_of_a_tasking_dpu(dpus: DpuFarm, url: str,
                                                                 tmp_path: Path) -> None:
    before = _system(tmp_path, url)
    # p2 leaves, p3 (T = 20 ms) comes: it releases on its period's grid since the run's start.
    path = tmp_path / "after.yaml"
    path.write_text(SYSTEM.format(url=url).replace(
        "  - {id: 2, name: p2, dpu: 1, period_us: 12000, compute_us: 3000}",
        "  - {id: 3, name: p3, dpu: 1, period_us: 20000, compute_us: 5000}"))
    after = load(path, []).with_url(url)
    done = _switch(dpus, url, 6363, before, after)
    _clean(done)
    _contiguous(done.records, 1)
    p2 = _contiguous(done.records, 2)
    p3 = _contiguous(done.records, 3)
    # p2's last job is the one released before the switch (its carried job is lost with it,
    # as at a run's end: no record); p3's first release is its first 20 ms point after it.
    assert max(r.release_ns for r in p2) < done.at
    assert p3[0].release_ns == done.t0 + 43 * 20 * MS and p3[0].cycle == 43, (p3[0], done.at - done.t0)
    assert all(r.generation == done.g + 1 and r.asked_ns == 5 * MS for r in p3)


def test_live_switch_between_executives_is_refused_in_one_line(dpus: DpuFarm, url: str,
                                                               tmp_path: Path) -> None:
    before = _system(tmp_path, url)
    after = _system(tmp_path, url, "dpu.1.executive=cyclic", "dpu.1.minor_cycle_us=2000")
    dpus.start(1)
    control = Control(url)
    tap = Tap(url, 6464)
    try:
        assert control.wait_heard([1], 5.0) == []
        g = control.next_generation()
        assert control.push(config_message(before, g, 0, committed=False), [1]).ok
        control.start(g, 6464, time.time_ns() + 200 * MS, 1_500 * MS)
        _stage(control, config_message(after, g + 1, 6464, committed=False), [1])
        control.command(skelmsg.command_t.COMMIT, generation=g + 1, at_utc_ns=time.time_ns() + 100 * MS)
        assert control.wait_for(lambda: (1, 6464) in control.reports, 5.0)
        status = control.dpus[1].status
    finally:
        records = tap.close()
        control.close()
    refused = "a live switch between the cyclic and the tasking executive is not built: push between runs"
    assert status.reject_reason == refused, status.reject_reason
    assert status.generation == g and {r.generation for r in records} == {g}
    by_process = defaultdict(list)
    for r in records:
        by_process[r.process].append(r.cycle)
    assert all(c == list(range(c[0], c[0] + len(c))) for c in by_process.values())
