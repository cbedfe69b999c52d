"""The executives' logic on simulated time (`skel simulate`), with exact expectations.

Each test runs the real skel-dpu (its sanitizer build, as every test does) on virtual time:
no platform stalls, no wake-up latency, no network. So a figure either is what the theory
says, to the nanosecond the records keep, or the executive is wrong: nothing is retried and
nothing has a tolerance for the platform."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pandas as pd
from conftest import REPO, skel
from e2e.test_event import BURSTS, CHAIN, _events
from unit.test_schedule import MS, _system

import skeleton
from skeleton.host.sysfile.system import load
from skeleton.host.theory.predict import predict
from skeleton.host.theory.schedule import ideal_schedule, response_times

SERVO = REPO / "examples" / "servo.yaml"
RATE_MONOTONIC = [(2, 8), (4, 12), (6, 24)]  # C/T ms; U = 0.83; R = 2, 6, 20 ms


def simulate(out: Path, *args: str) -> dict:
    done = skel("simulate", *args, "--out", str(out), "--json")
    assert done.returncode in (0, 3), done.stdout + done.stderr
    return json.loads(done.stdout)


def _cycles(out: Path) -> pd.DataFrame:
    timing = skeleton.load_run(out).timing.to_pandas()
    timing = timing[timing.completed].copy()
    timing["task"] = timing.process - 1
    return timing


def _against_the_ideal_schedule(tmp_path: Path, tasks: list[tuple[int, int]], run_s: float) -> pd.DataFrame:
    """Every completed job's response and preemptions beside the ideal schedule's, to the ns."""
    out = tmp_path / "run"
    simulate(out, str(_system(tmp_path, tasks, run_s)))
    cycles = _cycles(out)
    ideal = ideal_schedule(tasks, math.ceil(run_s * 1000) + 1000)
    epoch = (cycles.release_ns - cycles.cycle * cycles.task.map(lambda i: tasks[i][1] * MS * 1000)).min()
    for row in cycles.itertuples():
        job = ideal[(row.task, row.cycle)]
        assert row.release_ns - epoch == job.release * MS * 1000, row
        assert round(row.response_us * 1000) == job.response * MS * 1000, (row.task, row.cycle, job)
        assert row.preemptions == job.preemptions, (row.task, row.cycle, row.preemptions, job)
    return cycles


def test_rate_monotonic_responses_are_the_ideal_schedules_to_the_nanosecond(tmp_path: Path) -> None:
    rta = response_times(RATE_MONOTONIC)
    assert rta == [2, 6, 20]
    cycles = _against_the_ideal_schedule(tmp_path, RATE_MONOTONIC, 2.0)
    worst = cycles.groupby("task").response_us.max().tolist()
    assert worst == [r * MS for r in rta]  # the response-time analysis's bound, reached
    # p2's responses: 6 ms at the critical instant, 4 ms when p1 is not released with it
    assert sorted(set(cycles[cycles.task == 1].response_us)) == [4 * MS, 6 * MS]
    assert not cycles.overrun.any()
    assert cycles[cycles.task == 2].preemptions.max() >= 2


def test_an_unschedulable_set_misses_exactly_the_deadlines_of_the_ideal_schedule(tmp_path: Path) -> None:
    tasks = [(3, 8), (6, 20), (6, 24)]  # U = 0.93; R3 = 30 ms > 24 ms
    cycles = _against_the_ideal_schedule(tmp_path, tasks, 1.0)
    ideal = ideal_schedule(tasks, 2000)
    missed = {(i, k) for (i, k), job in ideal.items() if job.response > tasks[i][1]}
    ran = set(zip(cycles.task, cycles.cycle, strict=True))
    assert set(zip(cycles.task[cycles.overrun], cycles.cycle[cycles.overrun], strict=True)) == missed & ran
    assert any(i == 2 for i, _ in missed & ran)


def test_servo_gives_table_1s_compute_to_a_hundredth_of_a_point(tmp_path: Path) -> None:
    report = simulate(tmp_path / "run", str(SERVO))
    paper = load(SERVO).reference
    assert paper is not None
    assert report["fatal"] is False and not report["faults"], report["faults"]
    for dpu in report["dpus"]:
        assert abs(dpu["compute_pct"] - paper.dpus[dpu["id"]].compute_pct) <= 0.01, dpu
        # nothing of the platform on virtual time: every cycle starts at its release
        assert dpu["release_latency_us"]["max"] == 0.0 and dpu["stall_ms"] == 0.0, dpu


def test_servo_at_2_5_ms_locks_each_dpu_out_at_the_instant_the_prediction_gives(tmp_path: Path) -> None:
    path = REPO / "examples" / "servo-2.5ms.yaml"
    report = simulate(tmp_path / "run", str(path))
    predicted = {d.id: d.lockout_ms for d in predict(load(path)).dpus if d.lockout_ms is not None}
    assert set(predicted) == {1, 2, 3}
    first: dict[int, float] = {}
    for fault in report["faults"]:
        if fault["kind"] == "lockout":
            first[fault["dpu"]] = min(first.get(fault["dpu"], math.inf), fault["at_s"] * 1000)
    assert first == predicted
    # run.stop_on: the simulation stopped where `skel run` stops, one lockout window later
    assert report["stopped"] is not None, report["stopped"]
    # ... and the paper's pipeline jam: the Jacobian transpose (DPU 3) needs new joint_state
    # every cycle, and its writer, the joint sensors on overloaded DPU 2, is locked out too
    jams = [f for f in report["faults"] if f["kind"] == "jam"]
    assert [(j["chain"], j["buffer"], j["root_dpu"]) for j in jams] == [
        (["jacobian_transpose", "joint_sensors"], "joint_state", 2)], jams
    assert jams[0]["detail"].startswith("DPU 2 overloaded"), jams[0]
    # an overloaded DPU's time is its processes': none of it overhead
    assert {d["id"]: d["overhead_pct"] for d in report["dpus"]} == {1: 0.0, 2: 0.0, 3: 0.0, 4: None}


def test_the_same_file_and_seed_give_the_same_log_and_report_byte_for_byte(tmp_path: Path) -> None:
    jitter = str(REPO / "examples" / "servo-jitter.yaml")
    a, b, c = tmp_path / "a", tmp_path / "b", tmp_path / "c"
    simulate(a, jitter, "--duration", "0.5")
    simulate(b, jitter, "--duration", "0.5")
    simulate(c, jitter, "--duration", "0.5", "-s", "run.seed=3")
    assert (a / "run.lcm").read_bytes() == (b / "run.lcm").read_bytes()
    assert (a / "report.json").read_bytes() == (b / "report.json").read_bytes()
    assert (a / "report.json").read_bytes() != (c / "report.json").read_bytes()  # the seed draws anew


def test_each_dpus_window_opens_at_warmup_cycles_of_its_longest_period(tmp_path: Path) -> None:
    out = tmp_path / "run"
    report = simulate(out, str(SERVO), "--duration", "3")
    assert report["warmup_cycles"] == 100
    system = load(SERVO)
    cycles = _cycles(out)
    t0 = cycles.release_ns.min()
    for process, mine in cycles.groupby("process"):
        p = system.process(int(process))
        window_ns = 100 * max(q.period_us for q in system.processes if q.dpu == p.dpu) * 1000
        first = mine[mine.measured].release_ns.min() - t0
        assert window_ns <= first < window_ns + p.period_us * 1000, (p.name, first, window_ns)
        assert not mine[mine.release_ns - t0 < window_ns].measured.any(), p.name


def test_an_event_queue_keeps_the_newest_or_the_oldest_and_each_job_runs_when_the_schedule_says(
        tmp_path: Path) -> None:
    # the system tests/e2e/test_event.py runs on real time
    path = tmp_path / "bursts.yaml"
    path.write_text(BURSTS.replace("COMPUTE", "sleep"))
    out = tmp_path / "run"
    simulate(out, str(path))
    got = _cycles(out)
    got = got[got.event_ns >= 0]
    first = got.event_ns.min()
    ms = MS * 1000
    # Per burst at s: `newest` (the higher priority) runs at once on the first event, and a
    # period later on the last (the 3 between dropped); `oldest` runs after it, on the first,
    # then on the two it kept, a period apart (2 dropped). To the nanosecond, in every burst
    # (the tenth, at 2.0 s, has its third job at 2.1 s: the run's end).
    expected = {"newest": [(0, 0, 0), (2.0, 50.0, 3)],
                "oldest": [(0, 0.2, 0), (0.5, 50.2, 2), (1.0, 100.0, 0)]}
    for burst in range(9):
        s = first + burst * 200 * ms
        for name, jobs in expected.items():
            mine = got[(got.process_name == name) & (got.event_ns >= s) & (got.event_ns < s + 200 * ms)]
            seen = [((e - s) / ms, (b - s) / ms, d) for e, b, d in
                    zip(mine.event_ns, mine.start_ns, mine.event_dropped, strict=True)]
            assert seen == jobs, (name, burst, seen)


def test_an_emitted_event_releases_its_reaction_at_once_above_the_servo_loop(tmp_path: Path) -> None:
    path = tmp_path / "chain.yaml"
    path.write_text(CHAIN.replace("SEED", "7").replace("COMPUTE", "sleep"))
    out = tmp_path / "run"
    simulate(out, str(path))
    cycles = _cycles(out)
    sensor = cycles[(cycles.process_name == "sensor") & cycles.completed]
    react = cycles[(cycles.process_name == "react") & cycles.completed]
    # The cyclic DPU takes the oldest pulse waiting at a frame it is due in, in order; one
    # that came with none waiting is taken at the next such frame, within one period.
    assert (sensor.start_ns == sensor.release_ns).all() and (sensor.start_ns >= sensor.event_ns).all()
    assert sensor.event_ns.is_monotonic_increasing and sensor.event_ns.is_unique
    alone = sensor[sensor.event_queued == 0].start_ns - sensor[sensor.event_queued == 0].event_ns
    assert (alone < 2 * MS * 1000).mean() > 0.5
    # Each sensor cycle fires `fresh` as its work ends, and the reaction runs on it at that
    # instant, preempting the servo loop: one reaction per sensor cycle, no wait at all.
    ends = sorted(sensor.start_ns + 300 * 1000)
    assert sorted(react.event_ns) == ends[:len(react)] and len(ends) - len(react) <= 1
    assert (react.start_ns == react.event_ns).all() and react.event_dropped.sum() == 0
    assert cycles[cycles.process_name == "servo"].preemptions.max() >= 1


def test_a_seed_draws_the_same_instants_and_another_seed_others(tmp_path: Path) -> None:
    """A generator's instants come from the run's seed alone (the real run draws the
    simulation's: tests/e2e/test_event.py)."""
    def pulses(seed: int, tag: str) -> list[int]:
        path = tmp_path / f"{tag}.yaml"
        path.write_text(CHAIN.replace("SEED", str(seed)).replace("COMPUTE", "sleep"))
        simulate(tmp_path / tag, str(path))
        return [e.sent_ns for e in _events(tmp_path / tag, "pulse")]

    first, again, other = pulses(7, "a"), pulses(7, "b"), pulses(8, "c")
    assert len(first) > 300 and first == again
    gaps, others = np.diff(first), np.diff(other)
    n = min(len(gaps), len(others))
    assert (gaps[:n] != others[:n]).mean() > 0.9


def test_no_simulated_response_exceeds_its_predicted_worst(tmp_path: Path) -> None:
    """The prediction's worst response (exact response-time analysis on the tasking executive,
    the frame schedule on the cyclic one) bounds every simulated job: the executives never do
    worse than the theory says, on any example that fits."""
    for name in ("servo", "servo-tasking", "servo-events", "pair-10ms-5ms"):
        path = REPO / "examples" / f"{name}.yaml"
        out = tmp_path / name
        simulate(out, str(path), "--duration", "1")
        worst = {p.name: p.response_us for p in predict(load(path)).processes}
        measured = _cycles(out).groupby("process_name").response_us.max()  # warm-up included
        assert len(measured) == len(worst), (name, measured)
        for process, most in measured.items():
            bound = worst[str(process)]
            assert bound is None or most <= bound, (name, process, most, bound)
        assert any(bound is not None for bound in worst.values())


PACED = """\
system: paced
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: sample, bytes: 64}]
processes:
  - {id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 1000, outputs: [sample]}
  - {id: 2, name: reader, dpu: 2, period_us: 5000, compute_us: 1000, sync: data, inputs: [sample]}
run: {duration_s: 1, warmup_cycles: 10, lockout_cycles: 10, stop_on: []}
"""


def test_a_data_reader_paced_by_a_slower_writer_skips_every_other_release(tmp_path: Path) -> None:
    """The reader (5 ms) gets a sample every 10 ms: its release without one waits, and its
    period passes: the next release is skipped, as the prediction says (`paced by writer: it
    will run at 100 Hz`), never falling further behind."""
    path = tmp_path / "paced.yaml"
    path.write_text(PACED)
    report = simulate(tmp_path / "run", str(path))
    (reader,) = [p for p in report["processes"] if p["name"] == "reader"]
    assert reader["releases_skipped"] == reader["cycles"] == 94  # of 188 measured releases
    assert reader["inputs"][0]["new"] == reader["cycles"] and reader["inputs"][0]["dropped"] == 0
    assert reader["response_us"] == {"p50": 12000.0, "p99": 12000.0, "max": 12000.0}
    (skipping,) = [f for f in report["faults"] if f["kind"] == "skipping"]
    assert skipping["count"] == 94


def test_a_push_mid_run_switches_every_dpu_at_one_boundary_without_a_restart(tmp_path: Path) -> None:
    """`--push 2:FILE`: the executor's compute 3500 -> 3000 us is staged and committed for 2 s
    into the run; every DPU switches at the first boundary of the grid they share from then,
    and the new generation measures what its prediction says, to a hundredth of a point."""
    changed = tmp_path / "servo-3000.yaml"
    changed.write_text(SERVO.read_text().replace("name: executor, dpu: 2, period_us: 5000, compute_us: 3500",
                                                 "name: executor, dpu: 2, period_us: 5000, compute_us: 3000"))
    out = tmp_path / "run"
    report = simulate(out, str(SERVO), "--duration", "6", "--push", f"2:{changed}")
    assert report["generations"] == [1, 2] and report["generation"] == 2
    assert (out / "system-g2.yaml").read_text() == changed.read_text()
    (dpu2,) = [d for d in report["dpus"] if d["id"] == 2]
    assert abs(dpu2["compute_pct"] - 63.4) <= 0.01, dpu2
    cycles = skeleton.load_run(out).timing.to_pandas()
    t0 = cycles.release_ns.min()
    common_ns = math.lcm(5000, 23800) * 1000  # the grid all four DPUs share: 595 ms
    switch = {dpu: mine[mine.generation == 2].release_ns.min() - t0 for dpu, mine in cycles.groupby("dpu")}
    first = -(-2_000_000_000 // common_ns) * common_ns
    assert switch == dict.fromkeys((1, 2, 3, 4), first), switch
    last_old = {dpu: mine[mine.generation == 1].release_ns.max() - t0 for dpu, mine in cycles.groupby("dpu")}
    assert all(at < first for at in last_old.values()), last_old


DATA = """\
system: tasking-data
dpus: [{{id: 1, executive: threads}}, {{id: 2, executive: threads}}]
buffers: [{{id: 1, name: a, bytes: 64}}]
processes:
  - {{id: 1, name: fast1, dpu: 1, period_us: 2500, compute_us: 500}}
  - {{id: 2, name: writer, dpu: 1, period_us: 10000, compute_us: 2500, outputs: [a]}}
  - {{id: 3, name: fast2, dpu: 2, period_us: 2500, compute_us: 500}}
  - {{id: 4, name: reader, dpu: 2, period_us: 10000, compute_us: {reader}, sync: data, inputs: [a]}}
run: {{duration_s: 1.5, warmup_cycles: 2, lockout_cycles: 20, stop_on: []}}
"""


def test_a_live_switch_carries_a_tasking_job_waiting_for_its_data(tmp_path: Path) -> None:
    """The writer's buffer comes 3.5 ms after each 10 ms release (fast1 preempts it once), so at
    the grid point 2.5 ms into a period the reader's job waits for it: the switch there carries
    it, and it starts when its data comes, once, computing what the new plan asks."""
    before, after = tmp_path / "before.yaml", tmp_path / "after.yaml"
    before.write_text(DATA.format(reader=1000))
    after.write_text(DATA.format(reader=500))
    out = tmp_path / "run"
    simulate(out, str(before), "--push", f"0.8025:{after}")
    cycles = _cycles(out)
    t0 = cycles.release_ns.min()
    ms = MS * 1000
    fast = cycles[cycles.process.isin((1, 3)) & (cycles.generation == 2)]
    assert fast.release_ns.min() - t0 == 802.5 * ms  # both DPUs switch at the grid point
    reader = cycles[cycles.process == 4].set_index(cycles[cycles.process == 4].release_ns - t0)
    carried = reader.loc[800 * ms]
    assert carried.generation == 1 and carried.asked_ns == 500 * 1000  # the old plan's job, the new time
    assert (reader.start_ns - reader.index - t0 == 3.5 * ms).all()  # every job when its data comes
    assert (reader[reader.index < 800 * ms].asked_ns == 1000 * 1000).all()
    assert (reader[reader.index > 800 * ms].asked_ns == 500 * 1000).all()
    assert reader.completed.all()  # none skipped, cut short or locked out
