"""metrics.py and faults.py on hand-computed synthetic runs (real LCM encoding)."""

from __future__ import annotations

import dataclasses
from fractions import Fraction
from typing import Any

import numpy as np
import pytest
from analysis_synth import MS, RUN_ID, US, Rec, batches, small_config, small_run, status

import skelmsg
from skeleton.analysis.measure import faults as faults_module
from skeleton.analysis.measure import metrics
from skeleton.analysis.measure.faults import (
    Fault,
    behind_faults,
    behind_runs,
    code_faults,
    dpu_lost_faults,
    first_release_ns,
    heartbeats_from_status,
    jam_faults,
    lockout_faults,
    lockouts_from_status,
    skipping_faults,
    stall_events,
    stall_faults,
)
from skeleton.analysis.measure.metrics import (
    LatencyUs,
    ProcessMetrics,
    dpu_metrics,
    first_of_frame,
    first_of_frame_at,
    frame_release_latencies_ns,
    frames,
    process_metrics,
    static_load_pct,
    unstalled_lateness_us,
    unstalled_ns,
)
from skeleton.analysis.measure.tally import GenerationTally
from skeleton.analysis.measure.windows import Generation, run_stalls
from skeleton.analysis.read.records import RECORD_DTYPE, RunRecords, decode_run, lost_batches
from skeleton.host.model import Code, Process, System, from_config


def _lost(system: System, records: np.ndarray, *args: Any, **kwargs: Any) -> list[Fault]:
    """dpu_lost_faults of a run whose records are `records`."""
    return dpu_lost_faults(system, args[0], args[1], first_release_ns(records), *args[2:], **kwargs)


def _stalls(records: np.ndarray, config: Any) -> list[Fault]:
    """The stall faults of a run whose records are `records`."""
    system = from_config(config)
    return stall_faults(stall_events(records, system), system, first_release_ns(records))


def _behind(records: np.ndarray, config: Any) -> list[Fault]:
    """The behind faults of a run whose records are `records`."""
    system = from_config(config)
    return behind_faults(behind_runs(records, system), system, run_stalls(records))


def _run(dpu1: list[Rec], dpu2: list[Rec], size: int = 4) -> RunRecords:
    msgs = [t.encode() for t in batches(1, dpu1, size) + batches(2, dpu2, size)]
    return decode_run(msgs, RUN_ID)


def _exact(value: float | None, fraction: Fraction) -> None:
    assert value is not None
    assert abs(Fraction(value) - fraction) < Fraction(1, 10**12)


def test_a_dpu_behind_at_its_window_counts_its_time_from_the_end_of_its_warm_up_work() -> None:
    """The last warm-up cycle runs 4.51 ms into the window (an overloaded DPU does): that time
    is no measured cycle's, so the DPU's measured time begins when it ended, in the report and
    the live tables alike (the DPU's own sums, report.c, follow the same definition)."""
    dpu1, dpu2 = small_run(warmup=2, cycles=10)
    late = next(r for r in dpu1 if r.process == 1 and r.cycle == 1)  # B: the last warm-up cycle
    late.compute_ns += 5 * MS
    late.idle_ns = 0
    first = next(r for r in dpu1 if r.process == 0 and r.cycle == 2)  # A: the first measured one
    first.start_ns = late.end_ns + 100 * US  # one cycle at a time
    config = small_config(warmup_cycles=2)
    run = _run(dpu1, dpu2)
    d1 = dpu_metrics(run.records, from_config(config))[0]
    assert d1.elapsed_ms == pytest.approx(80.0 - 4.51)  # r9 + 10 ms - (r2 + 4.51 ms)
    live = GenerationTally(Generation.of(config))
    assert live.add(run.records[run.records["dpu"] == 1])
    assert live.dpus[0].elapsed_ms == d1.elapsed_ms and live.dpus[0].shares_pct[0] == d1.compute_pct


def test_dpu_utilization_matches_hand_computation() -> None:
    config = small_config(warmup_cycles=2)
    run = _run(*small_run(warmup=2, cycles=10))
    d1, d2 = dpu_metrics(run.records, from_config(config))
    # Measured cycles 2..9 of DPU 1: elapsed = r9 + 10 ms - r2 = 80 ms.
    assert d1.elapsed_ms == 80.0
    _exact(d1.compute_pct, Fraction(100 * 8 * 6000, 80_000))  # A 4 ms + B 2 ms per cycle = 60 %
    _exact(d1.communicate_pct, Fraction(100 * 8 * 800, 80_000))  # 200+300+100+200 µs = 8 %
    # wait: B blocked 500 µs + idle (2500 - 10k) µs, k = 2..9
    _exact(d1.wait_pct, Fraction(100 * (8 * 3000 - 10 * sum(range(2, 10))), 80_000))
    _exact(d1.overhead_pct, Fraction(100) - Fraction(60) - Fraction(8) - Fraction(2356, 80))
    for d in (d1, d2):
        total = d.compute_pct + d.communicate_pct + d.wait_pct + d.overhead_pct  # type: ignore[operator]
        assert abs(total - 100.0) < 1e-9
    assert d1.configured_cycle_ms == 10.0 and d2.configured_cycle_ms == 20.0
    # Earliest start in each minor cycle is A's: r + (100 + 10k) µs, so 10.01 ms apart.
    assert d1.measured_cycle_ms == pytest.approx(10.01, abs=1e-12)
    assert d1.processes == ["A", "B"] and d2.processes == ["C"]
    assert d1.static_load_pct == pytest.approx(60.0) and d2.static_load_pct == pytest.approx(25.0)
    assert (d1.overruns, d2.overruns) == (0, 1)
    assert d1.stall_pct == 0.0 and d1.compute_unstalled_pct == d1.compute_pct  # no stalls


def test_a_dpus_frames_are_the_same_whatever_order_its_records_come_in() -> None:
    """frames() skips its sort when the records come in minor order (a cyclic DPU's); a tasking
    DPU's long job ends after a later minor cycle's jobs, and those must sort as before."""
    rng = np.random.default_rng(7)
    mine = np.zeros(60, dtype=RECORD_DTYPE)
    mine["minor"] = np.repeat(np.arange(20), 3)
    mine["release_ns"] = mine["minor"] * 5 * MS
    mine["start_ns"] = mine["release_ns"] + rng.integers(10, 900, 60) * US
    expected = (np.arange(20), [int(s.min()) for s in np.split(mine["start_ns"], 20)],
                np.arange(20) * 5 * MS)
    for recs in (mine, mine[rng.permutation(60)]):
        got = frames(recs)
        assert [g.tolist() for g in got] == [np.asarray(e).tolist() for e in expected]


def test_a_frames_unstalled_wake_up_leaves_out_the_stalls_not_caught_up_on() -> None:
    """Three 5 ms frames of two records each: the first on time; the second 30 ms late, 28 ms
    of it stalls owed (debt_ns) at its first start; the third 2 ms early (a tasking job of the
    last frame that ran long is no wake-up). Whatever order the records come in, each frame is
    judged by the record that started first, and an early start stays."""
    mine = np.zeros(6, dtype=RECORD_DTYPE)
    mine["minor"] = [0, 0, 1, 1, 2, 2]
    mine["release_ns"] = mine["minor"] * 5 * MS
    mine["start_ns"] = [100 * US, 2 * MS, 35 * MS, 38 * MS, 8 * MS, 9 * MS]
    mine["debt_ns"] = [0, 0, 28 * MS, 31 * MS, 0, 0]
    expected = ([100 * US, 30 * MS, -2 * MS], [100 * US, 2 * MS, -2 * MS])
    # a later record that started first: its debt, not the one listed first's
    for recs in (mine, mine[[1, 0, 3, 2, 5, 4]], mine[::-1]):
        assert tuple(f.tolist() for f in frame_release_latencies_ns(recs)) == expected


def test_unstalled_time_takes_out_only_the_stalls_that_lengthened_the_run() -> None:
    """Ten 5 ms frames released 0..45 ms: their schedule is 50 ms."""
    mine = np.zeros(10, dtype=RECORD_DTYPE)
    mine["release_ns"] = np.arange(10) * 5 * MS
    # behind by the platform: 62 ms elapsed, 12 ms of it stalls -> its schedule
    assert unstalled_ns(mine, 62 * MS, 12 * MS, 5 * MS) == 50 * MS
    # stalls its idle time absorbed: it kept its schedule, nothing comes out
    assert unstalled_ns(mine, 50 * MS, 8 * MS, 5 * MS) == 50 * MS
    # overloaded by itself (no stall): what it took, however far past its schedule
    assert unstalled_ns(mine, 70 * MS, 0, 5 * MS) == 70 * MS
    # part of the stalls absorbed, part lengthened it: only that part comes out
    assert unstalled_ns(mine, 70 * MS, 8 * MS, 5 * MS) == 62 * MS
    assert unstalled_ns(mine, None, 0, 5 * MS) is None


def test_unstalled_lateness_leaves_out_the_stalls_not_caught_up_on() -> None:
    recs = np.zeros(4, dtype=RECORD_DTYPE)
    recs["debt_ns"] = [9 * MS, 0, 3 * MS, 2 * MS]
    lateness = np.array([10_000.0, 700.0, 2_000.0, -50.0])  # µs
    # 10 ms late with 9 ms of stalls owed: 1 ms is the design's; none owed: all of it; more owed
    # than late: on time; an early start (a computation shorter than configured) stays early
    assert unstalled_lateness_us(recs, lateness).tolist() == [1_000.0, 700.0, 0.0, -50.0]


@pytest.mark.parametrize(("stall_us", "debt_us", "explained"), [
    (0, 0, 0),      # no stall: the design's
    (300, 0, 1),    # its own stalls cover the 250 us
    (0, 300, 0),    # stalls owed explain only how late it started: 50 us
    (300, 300, 0),  # the frame's wake-up stall, in both: once, 300 - 300 + 50
    (550, 300, 1),  # 250 us its own beyond the wake-up, + 50
])
def test_an_overrun_is_the_platforms_when_stalls_cover_its_overshoot(stall_us: int, debt_us: int,
                                                                     explained: int) -> None:
    dpu1, dpu2 = small_run(warmup=2, cycles=10)
    late = dpu2[-1]  # DPU 2's only process: the first of its frame, 50 us after its release, 250 us past
    assert late.slack_ns == -250 * US and late.start_ns - late.release_ns == 50 * US
    late.stall_ns, late.debt_ns = stall_us * US, debt_us * US  # its own stalls, those still owed
    run = _run(dpu1, dpu2)
    c = process_metrics(run.records, run.inputs, from_config(small_config(warmup_cycles=2)))[2]
    assert (c.overruns, c.overruns_stalled) == (1, explained)


@pytest.mark.parametrize("huge", [False, True])
def test_process_metrics_counts_latency_and_inputs(huge: bool, monkeypatch: pytest.MonkeyPatch) -> None:
    if huge:  # a system too large for the table of its (process, buffer) inputs: they are searched
        monkeypatch.setattr(metrics, "_PAIR_TABLE_MAX", 0)
    config = small_config(warmup_cycles=2)
    run = _run(*small_run(warmup=2, cycles=10))
    a, b, c = process_metrics(run.records, run.inputs, from_config(config))
    assert (a.name, a.cycles, a.overruns) == ("A", 8, 0)
    assert a.latency_us.p50 == pytest.approx(155.0) and a.latency_us.max == pytest.approx(190.0)
    assert a.latency_us.p99 == pytest.approx(120 + 0.99 * 70)
    assert a.compute_mean_us == pytest.approx(4000.0)
    assert (a.late, a.too_late) == (0, 0)
    assert a.lateness_unstalled_us == a.lateness_us and a.late_unstalled == a.late  # no stalls owed
    # B starts 4.72..4.79 ms after its release: late (> 40 % of 10 ms), not too late (> 80 %).
    assert (b.late, b.too_late) == (8, 0)
    (b_in,) = b.inputs
    assert (b_in.buffer, b_in.buffer_id, b_in.new, b_in.stale, b_in.dropped, b_in.received) == (
        "a_out", 0, 6, 2, 2, 6
    )  # fmt: skip
    assert [(i.new, i.stale, i.dropped) for i in a.inputs] == [(8, 0, 0)]
    assert (c.cycles, c.overruns, c.first_overrun_cycle) == (3, 1, 4)
    assert c.slack_min_us is not None and c.slack_min_us < 0
    assert [(i.buffer, i.new, i.dropped, i.received) for i in c.inputs] == [("b_out", 3, 3, 6)]
    # An input record of a buffer its process does not read in this config counts nowhere: C's
    # of b_out, when the config has C read a_out (B's input) instead.
    config.processes[2].inputs = [0]
    _, b2, c2 = process_metrics(run.records, run.inputs, from_config(config))
    assert [(i.buffer, i.new, i.stale, i.dropped, i.received) for i in c2.inputs] == [("a_out", 0, 0, 0, 0)]
    assert b2.inputs == b.inputs


def test_warmup_cycles_are_excluded_from_every_measure() -> None:
    recs = small_run(warmup=2, cycles=10)
    warm, cold = from_config(small_config(warmup_cycles=0)), from_config(small_config(warmup_cycles=2))
    with_warm = process_metrics(_run(*recs).records, _run(*recs).inputs, warm)
    without = process_metrics(_run(*recs).records, _run(*recs).inputs, cold)
    assert with_warm[0].cycles == 10 and without[0].cycles == 8
    assert with_warm[0].compute_mean_us == pytest.approx((2 * 6000 + 8 * 4000) / 10)
    assert without[0].compute_mean_us == pytest.approx(4000.0)
    d_warm = dpu_metrics(_run(*recs).records, from_config(small_config(warmup_cycles=0)))[0]
    assert d_warm.elapsed_ms == 100.0


def test_skipped_partial_cycle_counts_time_but_not_cycles() -> None:
    dpu1, dpu2 = small_run(warmup=2, cycles=10)
    r10 = 5_000 * MS + 10 * 10 * MS
    dpu1.append(Rec(1, 10, 10, r10, r10 + 100 * US, 100 * US, 3 * MS, flags=skelmsg.timing_t.FLAG_SKIPPED,
                    inputs=[(0, 9, 0, 0, 0)]))  # fmt: skip
    run = _run(dpu1, dpu2)
    config = small_config(warmup_cycles=2)
    d1 = dpu_metrics(run.records, from_config(config))[0]
    b = process_metrics(run.records, run.inputs, from_config(config))[1]
    assert (b.cycles, b.skipped) == (8, 1)
    assert (b.inputs[0].new + b.inputs[0].stale) == 8
    elapsed_us = 80_000 + 3_200  # the partial cycle ends 3.2 ms after r10
    _exact(d1.wait_pct, Fraction(100 * (8 * 3000 - 440 + 3000), elapsed_us))


def test_static_load_divides_by_speed() -> None:
    config = small_config()
    config.dpus[0].speed = 2.0
    assert static_load_pct(from_config(config), 1) == pytest.approx(30.0)


def test_lost_batches_from_batch_seq_gaps() -> None:
    dpu1, _dpu2 = small_run()
    msgs = batches(1, dpu1, 2)  # 10 batches, seq 0..9
    kept = [m.encode() for m in msgs if m.batch_seq not in (2, 5, 6)]
    run = decode_run([*kept, msgs[0].encode()], RUN_ID, expected_batches={1: 12})
    assert run.lost_batches == [
        {"dpu": 1, "from_seq": 2, "to_seq": 2},
        {"dpu": 1, "from_seq": 5, "to_seq": 6},
        {"dpu": 1, "from_seq": 10, "to_seq": 11},  # report_t says 12 were published
    ]
    assert run.duplicates == 1 and run.batches == 7
    assert lost_batches(np.array([3, 3]), np.array([1, 2])) == [{"dpu": 3, "from_seq": 0, "to_seq": 0}]


def test_resent_batches_rejoin_their_place() -> None:
    """Batches the logger missed come back (host/live/repair.py) after later ones, some twice:
    the records end up as if nothing had been missed."""
    dpu1, dpu2 = small_run()
    first = [m.encode() for m in batches(1, dpu1, 2) + batches(2, dpu2, 2)]
    whole = decode_run(first, RUN_ID)
    late = [m.encode() for m in batches(1, dpu1, 2) if m.batch_seq in (2, 5)]
    holed = [m for m in first if m not in late]
    run = decode_run([*holed, *late, late[0]], RUN_ID)
    assert run.lost_batches == [] and run.duplicates == 1 and run.batches == whole.batches
    for d in (1, 2):
        mine = run.records[run.records["dpu"] == d]
        assert np.all(np.diff(mine["batch_seq"]) >= 0)
        theirs = whole.records[whole.records["dpu"] == d]
        assert np.array_equal(np.sort(mine["cycle"]), np.sort(theirs["cycle"]))
    # Every input record still belongs to its own process's cycle.
    def inputs(r: RunRecords) -> list[tuple[int, ...]]:
        i = r.inputs
        return sorted(zip(*(i[k].tolist() for k in ("process", "cycle", "buffer", "seq")), strict=True))

    assert inputs(run) == inputs(whole) and len(inputs(run)) > 0


def test_jam_chain_back_to_overloaded_dpu() -> None:
    config = small_config()
    # A (DPU 1) cannot run: not waiting for data. B waits on A's a_out, C on B's b_out.
    statuses = [status(1, [(0, -1, 7), (1, 0, 7)]), status(2, [(2, 1, 4)]), status(1, [(1, 0, 9)])]
    locks = lockouts_from_status(statuses, RUN_ID)
    assert locks[1].cycle == 7  # first report kept
    lockouts = lockout_faults(locks, from_config(config))
    assert [(f.kind, f.process, f.dpu, f.buffer, f.writer, f.cycle) for f in lockouts] == [
        ("lockout", "A", 1, None, None, 7),
        ("lockout", "B", 1, "a_out", "A", 7),
        ("lockout", "C", 2, "b_out", "B", 4),
    ]
    (jam,) = jam_faults(locks, from_config(config))
    assert jam.kind == "jam" and jam.chain == ["C", "B", "A"]
    assert (jam.process, jam.buffer, jam.writer, jam.cycle) == ("C", "b_out", "B", 4)
    assert jam.dpu == 2 and jam.root_dpu == 1 and jam.static_load_pct == pytest.approx(60.0)
    assert "overloaded" in jam.detail


def test_circular_wait_is_one_jam_and_other_runs_are_ignored() -> None:
    config = small_config()
    config.buffers[2].writer = 2  # c_out from C, read by A: A <- C <- B <- A
    statuses = [status(1, [(0, 2, 5), (1, 0, 5)]), status(2, [(2, 1, 3)]), status(1, [(0, -1, 1)], run_id=7)]
    (jam,) = jam_faults(lockouts_from_status(statuses, RUN_ID), from_config(config))
    assert jam.chain == ["A", "C", "B", "A"]
    assert jam.detail.startswith("circular wait")


def test_deadlock_on_one_dpu_names_both_processes_and_the_circular_wait() -> None:
    config = small_config()
    config.processes[0].sync = 1  # A waits for c_out, now written by B; B waits for A's a_out
    config.buffers[2].writer = 1
    # A blocks DPU 1's one thread in its wait; B, held up behind it, never runs.
    locks = lockouts_from_status([status(1, [(0, 2, 0), (1, -1, 0, 0)])], RUN_ID)
    a, b = lockout_faults(locks, from_config(config))
    assert (a.process, a.buffer, a.writer) == ("A", "c_out", "B")
    assert (b.process, b.dpu, b.buffer) == ("B", 1, None)
    assert b.detail.startswith("held up behind A"), b.detail
    (jam,) = jam_faults(locks, from_config(config))
    assert jam.chain == ["A", "B", "A"]
    assert jam.detail == ("circular wait: A -> B -> A (A waits on c_out from B; "
                          "B is held up behind A on DPU 1)"), jam.detail


def test_a_data_synchronised_process_is_jammed_by_its_locked_out_writer() -> None:
    config = small_config()
    # Both found late at their start (no buffer named): C cannot complete a cycle without
    # new b_out, and B, its writer, is locked out on an overloaded DPU.
    locks = lockouts_from_status([status(1, [(1, -1, 7)]), status(2, [(2, -1, 4)])], RUN_ID)
    (jam,) = jam_faults(locks, from_config(config))
    assert jam.chain == ["C", "B"]
    assert (jam.process, jam.buffer, jam.writer, jam.root_dpu) == ("C", "b_out", "B", 1)
    assert jam.detail.startswith("DPU 1 overloaded"), jam.detail
    # A periodic reader does not wait for its writer: no jam through it.
    config.processes[2].sync = 0
    assert jam_faults(locks, from_config(config)) == []


def test_a_lockout_says_when_its_cycles_window_ended_not_when_it_was_found() -> None:
    """at_s is r_k + lockout_cycles x period from the DPU's first release: the definition's
    instant, the same whether the DPU found it then or later (a stall it did not count)."""
    config = small_config()  # A: 10 ms on DPU 1, C: 20 ms on DPU 2, lockout_cycles 5
    t0 = 5_000 * MS
    beat = status(1, [(0, -1, 7)])
    beat.lockouts[0].release_ns = t0 + 70 * MS
    late = status(2, [(2, 1, 4)])
    late.lockouts[0].release_ns = t0 + 80 * MS
    locks = lockouts_from_status([beat, late], RUN_ID)
    a, c = lockout_faults(locks, from_config(config), {1: t0, 2: t0})
    assert (a.process, a.cycle, a.at_s) == ("A", 7, pytest.approx(0.120)), a
    assert a.detail.endswith("; not completed by 0.120 s"), a.detail
    assert (c.process, c.cycle, c.at_s) == ("C", 4, pytest.approx(0.180)), c
    # without the run's first releases, or a release (an old DPU's heartbeat), no instant
    unreleased = lockouts_from_status([status(1, [(0, -1, 7)])], RUN_ID)
    assert [f.at_s for f in lockout_faults(unreleased, from_config(config), {1: t0})] == [None]
    assert [f.at_s for f in lockout_faults(locks, from_config(config))] == [None, None]
    # a jam is dated by its head's lockout
    chained = locks | lockouts_from_status([status(1, [(1, 0, 7)])], RUN_ID)  # B waits on A's a_out
    (jam,) = jam_faults(chained, from_config(config), {1: t0, 2: t0})
    assert jam.chain[0] == "C" and jam.at_s == pytest.approx(0.180), jam


def test_lockout_without_locked_writer_is_not_a_jam() -> None:
    locks = lockouts_from_status([status(1, [(1, 0, 5)])], RUN_ID)
    assert jam_faults(locks, from_config(small_config())) == []
    assert [f.kind for f in lockout_faults(locks, from_config(small_config()))] == ["lockout"]


def _spans(dpu_releases_ms: dict[int, list[float]]) -> np.ndarray:
    rows = [(dpu, int(ms * 1e6)) for dpu, releases in dpu_releases_ms.items() for ms in releases]
    records = np.zeros(len(rows), dtype=RECORD_DTYPE)
    records["dpu"] = [r[0] for r in rows]
    records["release_ns"] = [r[1] for r in rows]
    return records


def _status(dpu: int, pid: int = 100, run_id: int = RUN_ID,
            state: int = skelmsg.status_t.STATE_RUNNING) -> skelmsg.status_t:
    s = status(dpu, [], run_id)
    s.pid, s.state = pid, state
    return s


def _beats(dpu: int, from_s: float, to_s: float, pid: int = 100, run_id: int = RUN_ID,
           state: int = skelmsg.status_t.STATE_RUNNING) -> list[tuple[int, skelmsg.status_t]]:
    """A DPU's statuses at 5 Hz from `from_s` to `to_s`, with when they were heard (µs)."""
    steps = round((to_s - from_s) * 5)
    return [(int((from_s + i / 5) * 1e6), _status(dpu, pid, run_id, state)) for i in range(steps + 1)]


def _one_process_per_dpu(dpus: tuple[int, ...]) -> System:
    """A System whose DPUs `dpus` run one process each (what dpu_lost_faults reads of it)."""
    return dataclasses.replace(from_config(small_config()), processes=tuple(
        Process(id=i, name=f"P{i}", dpu=i, order=1, period_us=5000, compute_us=0, sync="periodic",
                inputs=(), required=(), outputs=()) for i in dpus))


def test_dpu_lost_when_its_heartbeats_stop_not_when_its_timing_does() -> None:
    system = _one_process_per_dpu((1, 2, 3, 4))
    # DPU 3's timing stops 3.5 s early (a process waiting for data that never comes) while it
    # heartbeats to the end; DPU 2 falls silent at 1.4 s; DPU 4 is restarted (a new pid) at 1 s.
    records = _spans({1: [0, 4000], 2: [0, 1500], 3: [0, 500], 4: [0, 4000]})
    beats = (_beats(1, 0, 4) + _beats(2, 0, 1.4) + _beats(3, 0, 4) + _beats(4, 0, 1)
             + _beats(4, 1.2, 4, pid=101, run_id=0, state=skelmsg.status_t.STATE_READY)
             + _beats(1, 4.2, 5, state=skelmsg.status_t.STATE_READY))
    # In the order a log gives them: each DPU's batch of statuses, not by time. DPUs 1 and 3
    # ran to the end and sent their report_t.
    faults = _lost(system, records, heartbeats_from_status(beats), RUN_ID, reported={1, 3})
    assert [(f.kind, f.dpu) for f in faults] == [("dpu_lost", 2), ("dpu_lost", 4)], faults
    assert "not heard for 2.60 s from 1.40 s into the run" in faults[0].detail
    assert "restarted during the run (pid 100, then 101)" in faults[1].detail
    # Each heartbeat says when it was sent on its DPU's clock, its records' clock: the silence
    # is then placed from the run's first release, as every fault's at_s, not from the first
    # heartbeat heard (ARMED: here half a second before that release).
    for heard_us, s in beats:
        s.mono_ns = heard_us * 1000 - 500 * MS
    faults = _lost(system, records, heartbeats_from_status(beats), RUN_ID, reported={1, 3})
    assert "not heard for 2.60 s from 0.90 s into the run" in faults[0].detail, faults[0]
    assert faults[0].at_s == pytest.approx(0.9)
    # The logger stalled from 1 s to 3.5 s: it heard nobody then, so nobody who reported the
    # run is lost for it.
    stalled = [(t, s) for t, s in beats if not 1_000_000 < t < 3_500_000 and s.dpu != 4]
    assert _lost(system, records, heartbeats_from_status(stalled), RUN_ID, reported={1, 2, 3}) == []
    # Heartbeats of another run, or none at all: only a DPU with no timing record is lost.
    no_times = heartbeats_from_status([(None, _status(1, state=3)), (None, _status(3, state=3))])
    assert [f.dpu for f in _lost(system, _spans({1: [0, 9]}), no_times, RUN_ID)] == [2, 4]



def test_a_lost_dpu_names_the_real_code_it_ran_and_failed_steps_are_a_code_fault() -> None:
    """A crash in real code kills its DPU (dpu/code.c isolates nothing): the loss names the code's
    process. A step that failed (report_t's code_faults) is a fault of its process."""
    plain = _one_process_per_dpu((1, 2))
    system = dataclasses.replace(plain, processes=(
        plain.processes[0], dataclasses.replace(plain.processes[1], code=Code("sum", "sum_bytes"))))
    records = _spans({1: [0, 4000], 2: [0, 1500]})
    beats = _beats(1, 0, 4) + _beats(2, 0, 1.4)
    faults = _lost(system, records, heartbeats_from_status(beats), RUN_ID, reported={1})
    assert [f.dpu for f in faults] == [2]
    assert faults[0].detail.endswith("; it runs the real code of P2: a crash there is its DPU's loss")
    report = skelmsg.report_t()
    report.dpu = 2
    report.processes = [skelmsg.process_report_t(), skelmsg.process_report_t()]
    report.processes[0].process, report.processes[1].process = 1, 2
    report.processes[1].code_faults = 3
    found = code_faults(system, [report])
    assert [(f.kind, f.process, f.dpu, f.count, f.fatal) for f in found] == [("code", "P2", 2, 3, True)]


def test_dpu_lost_shortly_before_the_runs_end_when_it_sent_no_report() -> None:
    """A DPU killed 1.4 s before the run's end was silent for less than LOST_GAP_US within
    the run, which the report took for no fault. But a DPU that finished the run sends its
    report_t and heartbeats on while idle: silent past the end, with no report, it is lost."""
    system = _one_process_per_dpu((1, 2, 3))
    records = _spans({1: [0, 4000], 2: [0, 2600], 3: [0, 4000]})
    ready = skelmsg.status_t.STATE_READY
    # DPU 2 dies at 2.6 s; DPU 3 is restarted after the run (a new pid, no report for it)
    beats = (_beats(1, 0, 4) + _beats(2, 0, 2.6) + _beats(3, 0, 4)
             + _beats(1, 4.2, 9, state=ready) + _beats(3, 4.8, 9, pid=101, state=ready))
    faults = _lost(system, records, heartbeats_from_status(beats), RUN_ID, reported={1})
    assert [f.dpu for f in faults] == [2, 3], faults
    assert faults[0].detail.startswith("not heard for 1.40 s from 2.60 s into the run, to its end and after")
    assert "restarted at the run's end with no end-of-run report (pid 100, then 101)" in faults[1].detail
    # Its report_t: it finished the run, whatever came after (stopped, restarted)
    assert _lost(system, records, heartbeats_from_status(beats), RUN_ID, reported={1, 2, 3}) == []
    # A DPU that reported nothing but heartbeats on after the run (its report_t lost) is not lost
    alive = beats + _beats(2, 2.7, 9, state=ready)
    assert [f.dpu for f in _lost(system, records, heartbeats_from_status(alive), RUN_ID,
                                           reported={1, 3})] == []


def _cycles(dpu: int, process: int, period_ms: int, late_ms: list[float], stall_ms: dict[int, float],
            blocked_ms: dict[int, float] | None = None) -> np.ndarray:
    """One process's cycles 0.. on one DPU, one per minor cycle, started `late_ms[k]` after
    release, with the stalls (and data waits) their records carry."""
    records = np.zeros(len(late_ms), dtype=RECORD_DTYPE)
    k = np.arange(len(late_ms))
    records["dpu"], records["process"], records["cycle"], records["minor"] = dpu, process, k, k
    records["release_ns"] = k * period_ms * MS
    records["sched_ns"] = records["release_ns"]
    records["start_ns"] = records["release_ns"] + (np.array(late_ms) * MS).astype(np.int64)
    records["compute_ns"] = MS
    for cycle, ms in stall_ms.items():
        records["stall_ns"][cycle] = int(ms * MS)
    for cycle, ms in (blocked_ms or {}).items():
        records["blocked_ns"][cycle] = int(ms * MS)
    return records


def test_one_stall_of_a_host_is_one_fault_wherever_in_their_cycles_its_dpus_saw_it() -> None:
    """A record says how long its thread could not run, not where in the cycle: DPU 2 saw the
    80 ms stall on waking, then waited 90 ms for data from DPU 1, itself just resuming. It
    is still the stall DPU 1 saw (the report had split it in two: DPU 1 at 0.02 s, DPU 2 at
    0.11 s, each with fewer DPUs than stalled)."""
    late = [0.0] * 20
    late[2] = 80.0
    dpu1 = _cycles(1, 0, 10, late, {2: 80.0})
    dpu2 = _cycles(2, 2, 20, [0.0] * 10, {1: 80.0}, blocked_ms={1: 90.0})
    dpu2["start_ns"][1] = dpu1["start_ns"][2]
    # a wake-up's stall is also the executive's debt when its frame starts
    dpu1["debt_ns"][2] = dpu2["debt_ns"][1] = 80 * MS
    stalls = _stalls(np.concatenate([dpu1, dpu2]), small_config())
    assert [(f.dpus, round(f.duration_ms)) for f in stalls] == [([1, 2], 80)]
    assert stalls[0].at_s == pytest.approx(0.020)


def test_a_stall_is_dated_where_its_record_shows_it_was() -> None:
    """A stall inside a computation is in the cycle, from its start: the report had taken
    every stall to end at its cycle's start, and dated a 300 ms stop in a 1 ms computation
    300 ms early. A late wake-up is before the start, by as much as the cycle started late."""
    # The host's machine stopped from 52 to 352 ms: DPU 1 was computing cycle 5 (released at
    # 50 ms), DPU 2 asleep until its release at 60 ms, and woke then 292 ms late.
    dpu1 = _cycles(1, 0, 10, [0.0] * 40, {5: 300.0})
    dpu1["preempted_ns"][5] = 300 * MS  # a computation's stall is also its preempted time
    dpu2 = _cycles(2, 2, 20, [0.0, 0.0, 0.0, 292.0] + [0.0] * 16, {3: 292.0})
    dpu2["debt_ns"][3] = 292 * MS  # a wake-up's stall: the frame's debt starts from it
    (stall,) = _stalls(np.concatenate([dpu1, dpu2]), small_config())
    assert (stall.dpus, stall.at_s, stall.duration_ms) == ([1, 2], pytest.approx(0.050), 300.0), stall
    (alone,) = _stalls(dpu1, small_config())
    assert alone.at_s == pytest.approx(0.050), alone
    (woke,) = _stalls(dpu2, small_config())
    assert woke.at_s == pytest.approx(0.060), woke
    # The tasking executive keeps no debt: what preempted_ns does not hold, as far as the
    # job started late, was before its start.
    tasking = small_config()
    for d in tasking.dpus:
        d.executive = skelmsg.dpu_t.EXECUTIVE_THREADS
    dpu2["debt_ns"][3] = 0
    (woke,) = _stalls(dpu2, tasking)
    assert woke.at_s == pytest.approx(0.060), woke
    (alone,) = _stalls(dpu1, tasking)
    assert alone.at_s == pytest.approx(0.050), alone


def test_a_dpu_behind_from_a_stall_in_its_warm_up_is_the_platform_not_the_design() -> None:
    """A stall of 80 ms at 10 ms, in the warm-up (20 cycles); the DPU catches up 0.5 ms per
    minor cycle, so it is still 70 ms behind when the window opens at 200 ms. The stall is
    its cause: the report had looked for it only just before the window and blamed the design."""
    late = [0.0, *(max(0.0, 80.0 - 0.5 * k) for k in range(199))]
    config = small_config(warmup_cycles=20)
    config.processes = [p for p in config.processes if p.dpu == 1][:1]
    config.nprocesses = 1
    faults = _behind(_cycles(1, 0, 10, late, {1: 80.0}), config)
    assert len(faults) == 1 and not faults[0].fatal, faults
    assert faults[0].at_s == pytest.approx(0.010) and "kept from running for 80.0 ms" in faults[0].detail


def test_a_dpu_back_behind_after_a_dip_owes_it_to_the_stalls_since_it_was_on_schedule() -> None:
    """Two stalls under a minor cycle each (8 ms, then 6 ms 29 cycles later) on a DPU that makes
    up 0.05 ms a cycle: the second puts it 12.55 ms behind, 300 ms after the first, which only
    half the lateness lies within. The report had looked back as far as the lateness only, found
    the 6 ms stall short of half, and blamed the design (CI, 2026-12-03: `long overran ...
    (computed 3.3 ms), too little slack to catch up`, the computation exactly what was asked)."""
    late = [0.0] + [8.0 - 0.05 * k for k in range(29)]
    late += [late[-1] - 0.05 + 6.0 - 0.05 * k for k in range(120)]
    config = small_config(warmup_cycles=0)
    config.processes = [p for p in config.processes if p.dpu == 1][:1]
    config.nprocesses = 1
    faults = _behind(_cycles(1, 0, 10, late, {1: 8.0, 30: 6.0}), config)
    assert len(faults) == 1 and not faults[0].fatal, faults
    assert faults[0].at_s == pytest.approx(0.300) and "kept from running for 14.0 ms" in faults[0].detail
    # The same lateness with no stall before the run of late frames is the design's.
    faults = _behind(_cycles(1, 0, 10, late, {30: 6.0}), config)
    assert len(faults) == 1 and faults[0].fatal, faults


def test_a_dpu_behind_only_in_its_warm_up_is_no_fault() -> None:
    late = [0.0, *(max(0.0, 80.0 - 8.0 * k) for k in range(49))]
    config = small_config(warmup_cycles=20)
    config.processes = [p for p in config.processes if p.dpu == 1][:1]
    config.nprocesses = 1
    assert _behind(_cycles(1, 0, 10, late, {1: 80.0}), config) == []


@pytest.mark.parametrize("seed", range(5))
def test_the_first_of_a_frame_found_among_its_frames_only_is_the_one_found_among_all(seed: int) -> None:
    """process_metrics asks only for its overruns' frames: same answer, ties (equal starts) included."""
    rng = np.random.default_rng(seed)
    n = 400
    records = np.zeros(n, dtype=RECORD_DTYPE)
    records["dpu"] = rng.integers(1, 4, n)
    records["minor"] = rng.integers(0, 30, n)
    records["start_ns"] = rng.integers(0, 5, n)  # many ties
    rows = np.sort(rng.choice(n, int(rng.integers(0, 40)), replace=False))
    assert np.array_equal(first_of_frame_at(records, rows), first_of_frame(records)[rows])


def test_skipping_the_stalls_of_its_dpu_or_its_writers_explain_is_the_platforms() -> None:
    """SERVO's Jacobian transpose (DPU 3, 5 ms) reads joint_state from DPU 2: 316 releases
    skipped are 1580 ms; a stall of half that on DPU 2 or 3 explains them, less does not."""
    from conftest import REPO

    from skeleton.host.sysfile.system import load

    system = load(REPO / "examples" / "servo.yaml")
    proc = next(p for p in system.processes if p.name == "jacobian_transpose")
    skipping = ProcessMetrics(proc.id, proc.name, proc.dpu, proc.period_us, 784, 0, 0, LatencyUs(0, 0, 0),
                              None, None, 0, 0, releases_skipped=316)

    def fatal(stalls: dict[int, float]) -> list[bool | None]:
        return [f.fatal for f in skipping_faults([skipping], system, stalls)]

    assert fatal({}) == [True]
    assert fatal({3: 789.0, 1: 5000.0}) == [True]      # DPU 1 writes nothing it reads
    assert fatal({2: 790.0}) == [False]                  # its writer's DPU
    (fault,) = skipping_faults([skipping], system, {3: 1401.7, 2: 1135.7})
    assert "DPU 3 was kept from running for 1402 ms meanwhile (stalls: the platform" in fault.detail


def test_the_stall_backlog_is_what_the_spare_time_has_not_paid_off() -> None:
    """At 90 % load a DPU pays off 0.1 ns a ns: 10 ms of stalls at 0 owe 5 ms at 50 ms, none
    at 100 ms; a second stall adds to what is still owed; a stall after the limit is not counted."""
    at, stall = np.array([0, 50 * MS, 200 * MS]), np.array([10 * MS, 4 * MS, 99 * MS])
    assert faults_module.stall_backlog_ns(at[:1], stall[:1], 50 * MS, 90.0) == 5 * MS
    assert faults_module.stall_backlog_ns(at[:1], stall[:1], 100 * MS, 90.0) == 0
    assert faults_module.stall_backlog_ns(at, stall, 60 * MS, 90.0) == 8 * MS
    assert faults_module.stall_backlog_ns(at[:0], stall[:0], 60 * MS, 90.0) == 0


def test_a_lockout_the_stalls_its_dpu_had_not_made_up_explain_is_the_platforms() -> None:
    """SERVO on the tasking executive: jacobian_update (DPU 4, 96.5 %, lowest priority, 23.8 ms,
    lockout window 238 ms) runs in the 3.5 % the others leave spare: 20 ms of stalls 10 ms before
    its release still owe 11.3 ms at its limit, which hold it off 323 ms; 3 ms of them owe none.
    On the cyclic executive what is owed is how late each frame starts: 11.3 ms, under half the
    window."""
    from conftest import REPO

    from skeleton.analysis.measure.faults import Lockout, stalled_dpus
    from skeleton.host.sysfile.system import load

    def explained(name: str, stalls_ms: list[float]) -> dict[int, str]:
        system = load(REPO / "examples" / name)
        proc = next(p for p in system.processes if p.name == "jacobian_update")
        release = 1000 * MS
        records = np.zeros(len(stalls_ms) + 1, dtype=RECORD_DTYPE)
        records["dpu"] = proc.dpu
        records["process"][:-1] = next(p.id for p in system.processes if p.name == "dynamics")
        records["process"][-1] = proc.id
        records["release_ns"][:-1] = release - 10 * MS
        records["stall_ns"][:-1] = [int(ms * MS) for ms in stalls_ms]
        records["release_ns"][-1], records["stall_ns"][-1] = release, 0
        lock = Lockout(proc.id, None, 10, release_ns=release)
        return stalled_dpus({proc.id: lock}, records, system)

    (why,) = explained("servo-tasking.yaml", [12.0, 8.0]).values()
    assert "had 11.3 ms of stalls still to make up by then, which hold it off 323 ms" in why
    assert "static load 96.5 %" in why
    assert explained("servo-tasking.yaml", [3.0]) == {}
    assert explained("servo.yaml", [12.0, 8.0]) == {}
    assert explained("servo.yaml", [120.0, 60.0]) != {}    # half the window still owed at its limit
