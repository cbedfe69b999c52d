"""Live reconfiguration seen from the wire: real DPUs switch plans at one cycle boundary.

The test plays the host itself (stage a generation, COMMIT it with an instant) and
judges the switch from what the DPUs publish: the SKEL_TIMING records (generation,
release, cycle, compute, input seqs), their status and their reports.
"""

from __future__ import annotations

import itertools
import time
from collections import defaultdict
from dataclasses import dataclass

from conftest import EXAMPLES, DpuFarm, TimingTap

import skelmsg
from skeleton.host.live.control import Control
from skeleton.host.live.wire import config_message
from skeleton.host.model import System
from skeleton.host.sysfile.system import load, with_url

PAIR = EXAMPLES / "pair-10ms-5ms.yaml"
MS = 1_000_000
MINOR_NS = 5 * MS  # both DPUs of the pair run a 5 ms minor cycle
PERIOD_NS = {1: 10 * MS, 2: 5 * MS, 3: 5 * MS, 4: 10 * MS}
RUNNING = skelmsg.status_t.STATE_RUNNING
READY = skelmsg.status_t.STATE_READY


def _pair(url: str, *overrides: str) -> System:
    return with_url(load(PAIR, ["run.warmup_cycles=5", *overrides]), url)


def _slower(url: str) -> System:
    """The same pair with every compute_us 500 -> 1500."""
    names = ("slow_writer", "fast_writer", "fast_reader", "slow_reader")
    return _pair(url, *(f"process.{n}.compute_us=1500" for n in names))


@dataclass(frozen=True)
class Rec:
    dpu: int
    generation: int
    process: int
    cycle: int
    minor: int
    release_ns: int
    compute_ns: int
    flags: int
    inputs: tuple[tuple[int, int], ...]  # (buffer, seq)


class Tap(TimingTap):
    """The run's records with the generation of their batch and the seqs their inputs read."""

    def __init__(self, url: str, run_id: int) -> None:
        self.batch_generations: dict[int, set[int]] = defaultdict(set)
        super().__init__(url, run_id)

    def _add(self, msg: skelmsg.timing_t) -> None:
        ins: dict[int, list[tuple[int, int]]] = defaultdict(list)
        for w in range(msg.ninputs):
            ins[msg.in_record[w]].append((msg.in_buffer[w], msg.in_seq[w]))
        self.batch_generations[msg.dpu].add(msg.generation)
        for i in range(msg.n):
            self.records.append(Rec(msg.dpu, msg.generation, msg.process[i], msg.cycle[i], msg.minor[i],
                                    msg.release_ns[i], msg.compute_ns[i], msg.flags[i], tuple(ins[i])))


def _stage(control: Control, config: skelmsg.config_t, ids: list[int]) -> None:
    """Broadcast an uncommitted config until every DPU in `ids` has staged (or refused) it."""
    generation = config.generation
    config.committed = 0

    def settled() -> bool:
        return all(i in control.dpus and (control.dpus[i].status.staged_generation >= generation
                                          or control.dpus[i].status.rejected_generation == generation)
                   for i in ids)

    deadline = time.monotonic() + 5.0
    while time.monotonic() < deadline and not settled():
        control.publish_config(config)
        control.wait_for(settled, 0.25)
    assert settled(), {i: control.dpus[i].status for i in ids if i in control.dpus}


def _begin_run(control: Control, system: System, ids: list[int], run_id: int, duration_s: float) -> int:
    generation = control.next_generation()
    pushed = control.push(config_message(system, generation, 0, committed=False), ids)
    assert pushed.ok and pushed.applied == ids, pushed
    control.start(generation, run_id, time.time_ns() + 200 * MS, int(duration_s * 1e9))
    assert control.wait_for(lambda: all(control.dpus[i].status.state == RUNNING
                                        and control.dpus[i].status.run_id == run_id for i in ids), 5.0)
    return generation


def _utc_to_mono(control: Control, dpu: int, utc_ns: int) -> int:
    st = control.dpus[dpu].status
    return utc_ns - (st.utc_ns - st.mono_ns)


@dataclass
class Switched:
    """A run in which generation `g` was switched to g + 1 by a COMMIT with an instant."""

    g: int
    records: list[Rec]
    at_mono: dict[int, int]  # the COMMIT's instant on each DPU's clock
    reports: dict[tuple[int, int], skelmsg.report_t]
    batch_generations: dict[int, set[int]]  # per DPU: the generations of its timing batches


def _switch_mid_run(dpus: DpuFarm, url: str, run_id: int, before: System, after: System,
                    duration_s: float) -> Switched:
    """DPUs 1 and 2 run `before`; `after` is staged, then committed for 300 ms later."""
    ids = [1, 2]
    dpus.start(*ids)
    control = Control(url)
    tap = Tap(url, run_id)
    try:
        assert control.wait_heard(ids, 5.0) == []
        g = _begin_run(control, before, ids, run_id, duration_s)
        _stage(control, config_message(after, g + 1, run_id, committed=False), ids)
        assert all(control.dpus[i].status.generation == g for i in ids)  # staged, not applied
        at_utc = time.time_ns() + 300 * MS
        control.command(skelmsg.command_t.COMMIT, generation=g + 1, at_utc_ns=at_utc)
        at_mono = {i: _utc_to_mono(control, i, at_utc) for i in ids}
        # A status comes at once with the new generation, while the run goes on.
        assert control.wait_for(lambda: all(control.dpus[i].status.generation == g + 1
                                            and control.dpus[i].status.state == RUNNING for i in ids), 2.0)
        assert control.wait_for(lambda: all((i, run_id) in control.reports for i in ids), 6.0)
    finally:
        records = tap.close()
        control.close()
    return Switched(g, records, at_mono, dict(control.reports), dict(tap.batch_generations))


def test_commit_mid_run_switches_every_dpu_at_one_release(dpus: DpuFarm, url: str) -> None:
    ids, run_id = [1, 2], 5151
    done = _switch_mid_run(dpus, url, run_id, _pair(url), _slower(url), 2.5)
    g, records, at_mono = done.g, done.records, done.at_mono
    switch = {}
    for dpu in ids:
        mine = [r for r in records if r.dpu == dpu]
        assert {r.generation for r in mine} == {g, g + 1}
        assert done.batch_generations[dpu] == {g, g + 1}
        switch[dpu] = min(r.release_ns for r in mine if r.generation == g + 1)
        # The first release of the 5 ms grid at or after the COMMIT's instant (clocks read
        # through the status, so allow a millisecond of conversion error).
        assert at_mono[dpu] - MS <= switch[dpu] < at_mono[dpu] + MINOR_NS + MS, (dpu, switch, at_mono)
        # Every record before the switch is the old generation, every one at or after it the new.
        assert all((r.generation == g + 1) == (r.release_ns >= switch[dpu]) for r in mine)
        old = sorted(r.compute_ns for r in mine if r.generation == g)
        assert old[len(old) // 2] < 1_000_000, old[len(old) // 2]      # 500 us asked
        assert min(r.compute_ns for r in mine if r.generation == g + 1) >= 1_490_000  # 1500 us
        report = done.reports[(dpu, run_id)]
        assert report.generation == g + 1
        for p in report.processes:
            after = sum(1 for r in mine if r.process == p.process and r.generation == g + 1)
            assert p.cycles > after, (p.process, p.cycles, after)  # sums over the whole run
    # Both DPUs switched at the same instant: same grid, same t0, same COMMIT instant.
    assert abs(switch[1] - switch[2]) < MINOR_NS, switch

    for process, period in PERIOD_NS.items():
        mine = [r for r in records if r.process == process]
        cycles = [r.cycle for r in mine]
        # Cycle numbers (the seq of the buffers written) go on by one: none repeated, none missing.
        assert cycles == list(range(cycles[0], cycles[0] + len(cycles))), (process, cycles)
        releases = [r.release_ns for r in mine]
        gaps = [b - a for a, b in itertools.pairwise(releases)]
        assert all(0 < gap <= period for gap in gaps), (process, sorted(set(gaps)))
        minors = [r.minor for r in mine]
        assert minors == sorted(minors) and len(set(minors)) == len(minors)
        seqs: dict[int, list[int]] = defaultdict(list)
        for r in mine:
            for buffer, seq in r.inputs:
                seqs[buffer].append(seq)
        for buffer, seen in seqs.items():
            assert seen == sorted(seen), (process, buffer)  # a reader never sees seq go back
            assert seen[-1] > 0


def test_commit_mid_run_switches_dpus_of_different_minor_cycles_at_one_instant(dpus: DpuFarm,
                                                                                url: str) -> None:
    # DPU 1 runs a 10 ms minor cycle, DPU 2 a 15 ms one: their grids meet every 30 ms.
    rates = ("process.fast_writer.period_us=10000", "process.fast_reader.period_us=15000",
             "process.slow_reader.period_us=15000")
    common_ns = 30 * MS
    slower = _pair(url, *rates, "process.slow_writer.compute_us=1500", "process.fast_reader.compute_us=1500")
    # 300 ms after now is on no grid: each DPU's own next release would differ by up to 15 ms.
    done = _switch_mid_run(dpus, url, 5252, _pair(url, *rates), slower, 2.0)
    g, records, at_mono, ids = done.g, done.records, done.at_mono, [1, 2]
    t0 = min(r.release_ns for r in records)  # the run's first release: minor 0 of both DPUs
    switch = {d: min(r.release_ns for r in records if r.dpu == d and r.generation == g + 1) for d in ids}
    assert abs(switch[1] - switch[2]) < MS, switch
    for d in ids:
        assert at_mono[d] - MS <= switch[d] < at_mono[d] + common_ns + MS, (d, switch, at_mono)
        offgrid = (switch[d] - t0) % common_ns
        assert min(offgrid, common_ns - offgrid) < MS, (d, offgrid)


def test_commit_for_a_generation_not_staged_changes_nothing(dpus: DpuFarm, url: str) -> None:
    ids, run_id = [1, 2], 5252
    dpus.start(*ids)
    control = Control(url)
    tap = Tap(url, run_id)
    try:
        assert control.wait_heard(ids, 5.0) == []
        g = _begin_run(control, _pair(url), ids, run_id, 1.5)
        # DPU 2 refuses generation g+1 (its part asks for an executive it lacks); DPU 1 stages it.
        bad = config_message(_slower(url), g + 1, run_id, committed=False)
        bad.dpus[[d.id for d in bad.dpus].index(2)].executive = skelmsg.dpu_t.EXECUTIVE_THREADS
        _stage(control, bad, ids)
        assert control.dpus[1].status.staged_generation == g + 1
        assert control.dpus[2].status.rejected_generation == g + 1
        # A COMMIT to the DPU that never staged it, and one for a generation nobody has.
        soon = time.time_ns() + 100 * MS
        control.command(skelmsg.command_t.COMMIT, dpu=2, generation=g + 1, at_utc_ns=soon)
        control.command(skelmsg.command_t.COMMIT, generation=g + 9, at_utc_ns=soon)
        assert control.wait_for(lambda: all((i, run_id) in control.reports for i in ids), 5.0)
        assert "COMMIT for generation" in control.dpus[2].status.reject_reason
        for i in ids:
            assert control.dpus[i].status.generation == g
            assert control.reports[(i, run_id)].generation == g
        # Staged but never committed: a START for it is refused ...
        control.start(g + 1, run_id + 1, time.time_ns() + 100 * MS, 200 * MS)
        assert control.wait_for(lambda: "START for generation" in control.dpus[1].status.reject_reason, 2.0)
        assert control.dpus[1].status.state == READY
        # ... and a newer generation discards it: committing it afterwards is refused too.
        g2 = g + 2
        assert control.push(config_message(_pair(url), g2, 0, committed=False), ids).ok
        control.command(skelmsg.command_t.COMMIT, generation=g + 1)
        assert control.wait_for(lambda: "COMMIT for generation" in control.dpus[1].status.reject_reason, 2.0)
        assert control.dpus[1].status.generation == g2
    finally:
        records = tap.close()
        control.close()
    assert records and {r.generation for r in records} == {g}
    assert (1, run_id + 1) not in control.reports
    assert "discarded (never committed)" in dpus.log(1)


def test_restarted_dpu_catches_up_without_joining_the_run(dpus: DpuFarm, url: str) -> None:
    ids, run_id = [1, 2], 5353
    system = _pair(url)
    dpus.start(*ids)
    control = Control(url)
    try:
        assert control.wait_heard(ids, 5.0) == []
        g = _begin_run(control, system, ids, run_id, 2.0)
        dpus.kill(2)
        dpus.start(2)
        assert control.wait_for(lambda: control.dpus[2].status.pid == dpus.daemons[2].process.pid, 5.0)
        # The host's periodic re-send of the committed config, during DPU 1's run.
        committed = config_message(system, g, run_id, committed=True)
        for _ in range(20):
            control.publish_config(committed)
            if control.wait_for(lambda: control.dpus[2].status.generation == g, 0.2):
                break
        assert control.dpus[2].status.generation == g
        st = control.dpus[2].status
        assert (st.state, st.run_id, st.minor_cycles) == (READY, 0, 0)  # applied, not in the run
        assert control.dpus[1].status.state == RUNNING
        assert control.wait_for(lambda: (1, run_id) in control.reports, 5.0)
        assert (2, run_id) not in control.reports
        # Ready for the next run with no other step.
        control.start(g, run_id + 1, time.time_ns() + 200 * MS, 300 * MS)
        assert control.wait_for(lambda: all((i, run_id + 1) in control.reports for i in ids), 5.0)
        assert all(p.cycles > 0 for p in control.reports[(2, run_id + 1)].processes)
    finally:
        control.close()
