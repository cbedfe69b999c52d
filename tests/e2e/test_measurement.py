"""The numbers hold on any system: one measurement window per DPU, lateness against the
schedule, DPUs that fall behind, stalls of the machine, exact compute emulation.
Real DPUs (sanitizer build), real lcm-logger, real multicast with ttl=0."""

from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import pytest
from conftest import EXAMPLES, DpuFarm, skel, skel_background
from randsys import random_system

import skeleton
from skeleton.analysis.read.messages import open_run_log
from skeleton.analysis.read.records import load_records

pytestmark = pytest.mark.timing  # judges the DPUs' timing: tests/steal.py


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text())


def _process(report: dict, name: str) -> dict:
    return next(p for p in report["processes"] if p["name"] == name)


@pytest.mark.parametrize("seed", [11, 12, 13])
def test_random_mixed_period_systems_measure_their_configured_load(tmp_path: Path, url: str,
                                                                   seed: int) -> None:
    """Each process used to skip its own warm-up while the DPU's elapsed time began with
    its fastest process: a slow process's warm-up counted as time without compute in it."""
    text, load = random_system(seed)
    path = tmp_path / "random.yaml"
    path.write_text(text)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    for dpu in _report(out)["dpus"]:
        # unstalled: the window is what is judged here, not the platform's stalls
        assert dpu["compute_unstalled_pct"] == pytest.approx(load[dpu["id"]], abs=2.0), (seed, dpu, load)
        # The DPU's own sums (report_t) cover the same window.
    cross = _report(out)["cross_check"]
    for row in cross:
        ours, theirs = row["compute_ms"]
        assert ours == pytest.approx(theirs, rel=0.01), row


def test_late_is_judged_against_the_schedule_not_the_frame(tmp_path: Path, url: str) -> None:
    """forward_kinematics starts 1.2 ms into its 5 ms frame, after trajectory: that is its
    place in the schedule, not lateness (it used to be late in every cycle)."""
    out = tmp_path / "servo"
    run = skel("run", str(EXAMPLES / "servo.yaml"), "--spawn", "--url", url, "--cycles", "600",
               "-s", "run.warmup_cycles=20", "-s", "run.lockout_cycles=20", "--out", str(out), "--all")
    assert run.returncode == 0, run.stdout + run.stderr
    report = _report(out)
    for name in ("forward_kinematics", "force_control", "gravity_comp", "jacobian_update"):
        proc = _process(report, name)
        assert proc["latency_us"]["p50"] > 1000, proc  # its release latency includes those before it
        # The lateness its DPU's stalls explain left out (a VM's stolen time is not the
        # schedule's): judged against the schedule, its typical cycle is on time (was late) ...
        assert proc["lateness_unstalled_us"]["p50"] < 1000, proc
        # ... and late in next to no cycle (was every one). force_control follows
        # jacobian_transpose's wait for data from DPUs 1 and 2 in its minor cycle: their stalls
        # make it late too, counted as lateness on DPU 3 (README: lateness unstalled).
        if name != "force_control":
            assert proc["late_unstalled"] <= proc["cycles"] // 20, proc
    # The frame's own wake-up latency is its own measure: less the stalls its DPU had not
    # caught up on, as the processes' lateness (DPU 4, 96.5 % loaded, is behind for seconds
    # after a stall of the VM: 31 ms in one CI run, its frames then 1.8 ms late at p50).
    for dpu in report["dpus"]:
        assert dpu["release_latency_unstalled_us"]["p50"] < 1000, dpu
    assert "lateness" in run.stdout


HICCUP_SYSTEM = """\
system: hiccup
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: state, bytes: 64}]
processes:
  - {id: 1, name: sensor, dpu: 1, period_us: 5000, compute_us: 200, outputs: [state]}
  - {id: 2, name: controller, dpu: 2, period_us: 5000, compute_us: 3800, sync: data, inputs: [state]}
run: {duration_s: 4, warmup_cycles: 20, lockout_cycles: 40, stop_on: [lockout, jam]}
"""


def test_a_data_synchronised_dpu_catches_up_after_a_hiccup(tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    """A data-synchronised process gets one new sample per writer period: after a hiccup its
    DPU never caught up and ran periods behind to the end. It now skips the releases it has
    missed (cycle skipping), and its readers see them as dropped sequences."""
    path = tmp_path / "hiccup.yaml"
    path.write_text(HICCUP_SYSTEM)
    dpus.start(1, 2)
    out = tmp_path / "run"
    run = skel_background("run", str(path), "--url", url, "--out", str(out))
    time.sleep(3.0)  # the DPUs are 1-2 s into the run
    pid = dpus.daemons[2].process.pid
    os.kill(pid, signal.SIGSTOP)
    time.sleep(0.015)  # three periods: under the stall threshold's excuse, over a period behind
    os.kill(pid, signal.SIGCONT)
    assert run.wait(60) == 0, run.output
    report = _report(out)
    controller = _process(report, "controller")
    assert controller["releases_skipped"] >= 1, controller
    # Caught up: the bulk of its cycles start in their period, not periods behind.
    assert controller["latency_us"]["p99"] < 5000, controller
    assert not [f for f in report["faults"] if f["kind"] == "behind" and f["fatal"]], report["faults"]


OVERLOADED_SYSTEM = """\
system: overloaded
dpus: [{id: 1}]
processes:
  - {id: 1, name: heavy, dpu: 1, period_us: 5000, compute_us: 5300}
run: {duration_s: 2, warmup_cycles: 10, lockout_cycles: 100000, stop_on: []}
"""


def test_a_dpu_that_runs_behind_is_a_fault_of_its_own(tmp_path: Path, url: str) -> None:
    """A DPU whose release latency stays above a period: named, how far, since when, why;
    live, in the tables and report.json, and fatal (exit 3)."""
    path = tmp_path / "overloaded.yaml"
    path.write_text(OVERLOADED_SYSTEM)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out), "--all")
    assert run.returncode == 3, run.stdout + run.stderr
    behind = [f for f in _report(out)["faults"] if f["kind"] == "behind"]
    assert len(behind) == 1, _report(out)["faults"]
    fault = behind[0]
    assert fault["dpu"] == 1 and fault["fatal"]
    assert fault["behind_ms"] > 5.0 and fault["duration_ms"] > 100 and fault["at_s"] >= 0
    assert "overloaded" in fault["detail"]
    assert "FAULT behind: DPU 1" in run.stdout  # live
    assert "behind" in run.stdout.split("faults")[-1]  # the fault table
    plots = skel("report", str(out), "--plots", str(tmp_path / "plots"))
    assert plots.returncode == 3, plots.stdout + plots.stderr
    assert (tmp_path / "plots" / "schedule.png").stat().st_size > 10_000
    assert "behind its schedule" in (tmp_path / "plots" / "report.html").read_text()


def test_a_stall_of_the_machine_is_not_a_lockout(tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    """Every DPU of a host late by the same tens of ms at once is the platform stalling: a
    stall fault naming the host, when and how long; no lockout, no exit 3 (it was exit 3)."""
    dpus.start(1, 2, 3, 4)
    out = tmp_path / "run"
    run = skel_background("run", str(EXAMPLES / "servo.yaml"), "--url", url, "--duration", "4",
                          "-s", "run.warmup_cycles=20", "--out", str(out))
    # In the run, past the warm-up: a loaded machine may take seconds to start it.
    run.wait_started(lambda: dpus.logs(1, 2, 3, 4), 4)
    time.sleep(1.5)
    pids = [d.process.pid for d in dpus.daemons.values()]
    for pid in pids:
        os.kill(pid, signal.SIGSTOP)
    time.sleep(0.080)  # more than the 50 ms lockout of the 5 ms DPUs
    for pid in pids:
        os.kill(pid, signal.SIGCONT)
    code = run.wait(60)
    report = _report(out)
    assert code == 0, run.output
    kinds = [f["kind"] for f in report["faults"]]
    assert "lockout" not in kinds and "jam" not in kinds, report["faults"]
    stalls = [f for f in report["faults"] if f["kind"] == "stall" and f["duration_ms"] >= 50]
    assert stalls, report["faults"]
    assert stalls[0]["host"] == "localhost" and len(stalls[0]["dpus"]) >= 3, stalls
    assert not stalls[0]["fatal"]
    assert "STALL host localhost" in run.output


def test_a_lockout_the_writers_stalled_dpu_explains_is_the_platforms(tmp_path: Path, url: str,
                                                                     dpus: DpuFarm) -> None:
    """The reader's own stalls do not count towards its lockout; its writer's DPU stopped
    for 300 ms starves it all the same. Its lockout (and a jam on the writer) is named, with
    the writer's stall as the cause: the platform's, no exit 3 (it was a fatal flaw)."""
    dpus.start(1, 2)
    system = tmp_path / "hiccup.yaml"
    system.write_text(HICCUP_SYSTEM)
    out = tmp_path / "run"
    run = skel_background("run", str(system), "--url", url, "--out", str(out), "-s", "run.lockout_cycles=5",
                          "-s", "run.stop_on=[]")  # fmt: skip
    run.wait_started(lambda: dpus.logs(1, 2), 2)
    time.sleep(1.5)
    pid = dpus.daemons[1].process.pid
    os.kill(pid, signal.SIGSTOP)
    time.sleep(0.300)  # twelve times the controller's 25 ms lockout window
    os.kill(pid, signal.SIGCONT)
    code = run.wait(60)
    report = _report(out)
    locks = [f for f in report["faults"] if f["kind"] in ("lockout", "jam")]
    assert any(f["kind"] == "lockout" and f["process"] == "controller" for f in locks), report["faults"]
    for fault in locks:
        explained = "sensor's DPU 1 was kept from running" in fault["detail"]
        assert not fault["fatal"] and explained, fault["detail"]
    assert code == 0, run.output


def test_the_lateness_a_stall_explains_is_not_the_designs(tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    """A DPU 90 % loaded, stopped for 200 ms: it starts its cycles up to 200 ms late and catches
    up at 0.5 ms a cycle. All of that lateness is the stall's (timing_t.debt_ns): the design's
    own, lateness_unstalled, stays under late_pct (20 %) of the period."""
    path = tmp_path / "busy.yaml"
    path.write_text(ONE_DPU.format(long_us=LONG_US))
    dpus.start(1)
    out = tmp_path / "run"
    run = skel_background("run", str(path), "--url", url, "-s", "run.duration_s=5", "-s", "run.late_pct=20",
                          "-s", "run.lockout_cycles=100", "--out", str(out))
    run.wait_started(lambda: dpus.logs(1), 1)
    time.sleep(1.5)  # past the warm-up
    pid = dpus.daemons[1].process.pid
    stopped_ns = time.monotonic_ns()  # CLOCK_MONOTONIC, the records' clock on this host
    os.kill(pid, signal.SIGSTOP)
    time.sleep(0.2)
    os.kill(pid, signal.SIGCONT)
    assert run.wait(60) == 0, run.output
    report = _report(out)
    # The stall is dated where it was: 90 % of the time the stop falls in a computation, which
    # the report had dated 200 ms early (at its cycle's start less the stall).
    records = load_records(open_run_log(out / "run.lcm"), report["run_id"]).records
    stopped_s = (stopped_ns - int(records["release_ns"].min())) / 1e9
    (stall,) = [f for f in report["faults"] if f["kind"] == "stall" and f["duration_ms"] > 150]
    assert stopped_s - 0.05 < stall["at_s"] < stopped_s + 0.05, (stopped_s, stall)
    for proc in report["processes"]:
        assert proc["lateness_us"]["max"] > 150_000, proc  # the stop shows in the lateness ...
        assert proc["late"] > 100, proc  # ... for the 200 cycles of catching up
        assert proc["lateness_unstalled_us"]["max"] < 1000, proc  # ... none of it the design's (late_pct)
        assert proc["late_unstalled"] == 0, proc


RELAY_SYSTEM = """\
system: relay
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: raw, bytes: 64}, {id: 2, name: relayed, bytes: 64}]
processes:
  - {id: 1, name: sensor, dpu: 1, period_us: 5000, compute_us: 500, outputs: [raw]}
  - {id: 2, name: relay, dpu: 2, period_us: 5000, compute_us: 0, sync: data,
     inputs: [raw], outputs: [relayed]}
  - {id: 3, name: user, dpu: 2, period_us: 5000, compute_us: 1000, inputs: [relayed]}
run: {duration_s: 2, warmup_cycles: 10, stop_on: [lockout]}
"""


def test_a_process_of_zero_compute_only_communicates(tmp_path: Path, url: str) -> None:
    """compute_us: 0, a relay: it waits for its data and passes it on, computing nothing."""
    path = tmp_path / "relay.yaml"
    path.write_text(RELAY_SYSTEM)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    report = _report(out)
    relay, user = _process(report, "relay"), _process(report, "user")
    assert relay["cycles"] > 200 and relay["compute_mean_us"] == 0.0, relay
    assert relay["inputs"][0]["new"] == relay["cycles"], relay  # it ran on each new sample
    # and passed each one on: the user received them all, bar the last one, which its last
    # cycle may start before. How many its cycles found new is a race on this machine (its
    # DPU's loopback delivery against the user's start in the same frame), not the relay's.
    received = user["inputs"][0]["received"]
    assert relay["cycles"] - 1 <= received <= relay["cycles"], (relay, user)
    assert next(b for b in report["buffers"] if b["buffer"] == "relayed")["lost"] == 0, report["buffers"]


ORPHAN_SYSTEM = """\
system: orphan
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: state, bytes: 64}]
processes:
  - {id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 500, outputs: [state]}
  - {id: 2, name: reader, dpu: 2, period_us: 10000, compute_us: 500, sync: data, inputs: [state]}
run: {duration_s: 3, warmup_cycles: 10, lockout_cycles: 20}
"""


def test_a_stall_during_a_data_wait_delays_its_lockout_and_ends_nothing_else(
        tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    """The machine stalls while a data-synchronised reader waits for a writer that died. The
    stall delays its lockout by the stall's length, no more: the wait woke at the lockout's
    instant on the schedule, found it excused by the stall, and polled with a timeout in the
    past, that is forever (CI: the DPU missed the lockout and the run's end, and the whole wait
    was taken for a 4 s stall)."""
    path = tmp_path / "orphan.yaml"
    path.write_text(ORPHAN_SYSTEM)
    dpus.start(1, 2)
    out = tmp_path / "run"
    run = skel_background("run", str(path), "--url", url, "--out", str(out))
    run.wait_started(lambda: dpus.logs(1, 2), 2)
    time.sleep(1.0)
    dpus.kill(1)
    time.sleep(0.05)  # the reader waits for `state`, its lockout 200 ms after its release
    reader = dpus.daemons[2].process.pid
    os.kill(reader, signal.SIGSTOP)
    time.sleep(0.06)
    os.kill(reader, signal.SIGCONT)
    assert run.wait(60) == 3, run.output  # the reader's lockout: a fatal flaw
    assert "still running" not in run.output, run.output
    assert re.search(r"LOCKOUT process 2 cycle \d+ \(waiting on buffer 1\)", dpus.log(2)), dpus.log(2)
    report = _report(out)
    lockout = next(f for f in report["faults"] if f["kind"] == "lockout")
    assert (lockout["process"], lockout["buffer"]) == ("reader", "state"), report["faults"]
    long_stalls = [f for f in report["faults"] if f["kind"] == "stall" and f["duration_ms"] > 500]
    assert not long_stalls, report["faults"]


ONE_DPU = """\
system: compute
dpus: [{{id: 1, compute: sleep}}]
processes:
  - {{id: 1, name: short, dpu: 1, period_us: 5000, compute_us: 1200}}
  - {{id: 2, name: long, dpu: 1, period_us: 5000, compute_us: {long_us}}}
run: {{duration_s: 2, warmup_cycles: 20}}
"""
LONG_US = 3315  # with short's 1200 us, 90 % of the 5 ms period
# How far this VM's CPU speed moves within a run, between the DPU's two drift checks (its start and
# its end) and unseen by any witness outside the DPU: WORK's median computation came out 2.5 % over
# asked (drift 0.67 %) on the project's CI of ba363d9 and 3.4 % under (drift 1.1 %) on a fresh-clone
# CI of 5fb4d7b. WORK's accuracy to 0.5 % is `make bench`'s goal, against a quiet machine's floor;
# here it must only compute the calibrated work, within what the CPU's own speed does.
WORK_SPEED_SPREAD = 0.04


# WORK's DPU is 60 % loaded, the others 90 %: WORK runs at the CPU's speed of the moment, and
# a CPU 10 % slower than at calibration overruns a 90 % design and locks it out (CI: 18 % slower
# in three attempts in a row, none stolen in the two retries). That is WORK showing the platform, which
# this test does not judge; the others' computations are wall or CPU time and keep 90 %.
@pytest.mark.parametrize(("mode", "long_us"),
                         [("work", 1800), ("cpu", LONG_US), ("wall", LONG_US), ("sleep", LONG_US)])
def test_each_compute_mode_computes_what_is_asked(tmp_path: Path, url: str, mode: str, long_us: int) -> None:
    """One DPU alone: each mode computes what was asked within 1 %. WORK runs at
    the CPU's speed of the moment: a machine busier than at the DPU's start-up makes it slower,
    and the DPU says by how much (work_drift_pct, the larger of the drifts it measured at the
    run's start and end: CI once ran +2.4 % with 0.25 % at the start); beyond that within 1 %,
    and WORK within WORK_SPEED_SPREAD more, what the CPU's speed does between those checks.
    WORK is judged by its median computation, as the DPU measures its drift (the median of five
    runs): a shared CPU also runs single computations 2-4 times slower, no stall (here: median
    2.7 % above asked with a drift of 4.1 %, the mean 9.7 % above, p99 2.4 times the median)."""
    path = tmp_path / "compute.yaml"
    path.write_text(ONE_DPU.format(long_us=long_us))
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "-s", f"dpu.1.compute={mode}", "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    report = _report(out)
    drift = report["dpus"][0]["work_drift_pct"]
    assert (drift is None) == (mode != "work"), report["dpus"][0]
    for name, asked in (("short", 1200), ("long", long_us)):
        process = _process(report, name)
        measured = process["compute_us"]["p50"] if mode == "work" else process["compute_mean_us"]
        tolerance = 0.01 + abs(drift or 0) / 100 + (WORK_SPEED_SPREAD if mode == "work" else 0.0)
        assert measured == pytest.approx(asked, rel=tolerance), (mode, name, measured, drift)


PARTS_SYSTEM = """\
system: parts
dpus: [{{id: 1, executive: {executive}, compute: {mode}}}]
processes:
  - {{id: 1, name: fast, dpu: 1, period_us: 4000, compute_us: 1800}}
  - {{id: 2, name: slow, dpu: 1, period_us: 12000, compute_us: 2000}}
run: {{duration_s: 4, warmup_cycles: 2, lockout_cycles: 50, stop_on: []}}
"""
PARTS_PERIODS_NS = {1: 4_000_000, 2: 12_000_000}
# A DPU's last line of a run (dpu/control.c).
_RUN_STALLS = re.compile(rb"run -?\d+ ended: .*, longest platform stall ([\d.]+) ms")


def _longest_dpu_stall_ms(root: Path) -> float:
    """The longest platform stall any DPU whose log is under ROOT reported at the end of a run."""
    return max((float(m.group(1)) for log in root.rglob("dpu*.log")
                for m in _RUN_STALLS.finditer(log.read_bytes())), default=0.0)


@pytest.mark.parametrize(("executive", "mode"), [("cyclic", "sleep"), ("cyclic", "cpu"),
                                                 ("threads", "sleep"), ("threads", "cpu")])
def test_a_records_parts_add_up_to_where_its_work_ended(tmp_path: Path, url: str, dpus: DpuFarm,
                                                        executive: str, mode: str) -> None:
    """Response, plots and MCAP take a cycle's end from its record's parts (start + comm_in +
    blocked + preempted + compute + comm_out); the DPU took its slack from the real end. The
    two agree to the ns, also where the thread was stopped mid-computation: that time is in
    preempted_ns (and stall_ns), or a stalled cycle's response came out short by the stall."""
    path = tmp_path / "parts.yaml"
    path.write_text(PARTS_SYSTEM.format(executive=executive, mode=mode))
    dpus.start(1)
    out = tmp_path / "run"
    run = skel_background("run", str(path), "--url", url, "--out", str(out))
    run.wait_started(lambda: dpus.logs(1), 1)
    pid = dpus.daemons[1].process.pid
    # 62 % loaded: a stop lands in a computation 62 % of the time; twelve leave none inside
    # one with a chance of 0.38^12, 10^-5 (six: 0.3 %, and a run of the suite once met it)
    for _ in range(12):
        time.sleep(0.2)
        os.kill(pid, signal.SIGSTOP)
        time.sleep(0.02)
        os.kill(pid, signal.SIGCONT)
    assert run.wait(60) == 0, run.output
    t = skeleton.load_run(out).timing.to_pandas()
    t = t[t.completed]
    assert len(t) > 400
    real_end = t.release_ns + t.process.map(PARTS_PERIODS_NS) - t.slack_ns
    parts = t.start_ns + t.comm_in_ns + t.blocked_ns + t.preempted_ns + t.compute_ns + t.comm_out_ns
    off = t.assign(by=real_end - parts)[real_end != parts]
    assert off.empty, off[["process", "cycle", "preempted_ns", "stall_ns", "by"]]
    assert t.preempted_ns.max() >= 10_000_000, t.preempted_ns.describe()  # a stop was in there
    # The DPU's log says so at the run's end.
    waited = time.monotonic() + 5
    while _longest_dpu_stall_ms(tmp_path) < 10 and time.monotonic() < waited:
        time.sleep(0.05)
    assert _longest_dpu_stall_ms(tmp_path) >= 10, dpus.log(1)


STOPS_SYSTEM = """\
system: stops
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: frame, bytes: 1048576}]
processes:
  - {id: 1, name: camera, dpu: 1, period_us: 10000, compute_us: 500, outputs: [frame]}
  - {id: 2, name: viewer, dpu: 2, period_us: 10000, compute_us: 500, inputs: [frame]}
run: {duration_s: 3, warmup_cycles: 2, lockout_cycles: 50, stop_on: []}
"""


def test_every_stop_of_a_dpu_is_a_stall_wherever_it_lands(tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    """A stop of the writer's DPU is the platform's stall wherever in its cycle it lands:
    in its sleep, its computation, while it publishes a 1 MiB frame (to the kernel a
    sender stopped in a system call chose to wait, as one blocked on a full socket would)
    or between two steps, when it is already behind. Each of 16 stops of 25 ms is one
    record's stall of at least 15 ms (the 10 ms period less what was left of a sleep it
    cut short). A stop that none of them charged made its reader's lockout read as the
    design's flaw (test_a_lockout_the_writers_stalled_dpu_explains_is_the_platforms)."""
    path = tmp_path / "stops.yaml"
    path.write_text(STOPS_SYSTEM)
    dpus.start(1, 2)
    out = tmp_path / "run"
    run = skel_background("run", str(path), "--url", url, "--out", str(out))
    run.wait_started(lambda: dpus.logs(1, 2), 2)
    pid = dpus.daemons[1].process.pid
    stops = 16
    time.sleep(0.3)  # the run's first release is after the DPUs log that it started
    for i in range(stops):
        time.sleep(0.06 + 0.0037 * i)  # a phase that walks through the whole cycle
        os.kill(pid, signal.SIGSTOP)
        time.sleep(0.025)
        os.kill(pid, signal.SIGCONT)
    assert run.wait(60) == 0, run.output
    t = skeleton.load_run(out).timing.to_pandas()
    camera = t[t.process == 1]
    stalled = camera[camera.stall_ns >= 15_000_000]
    assert len(stalled) >= stops, camera[camera.stall_ns > 0][["cycle", "stall_ns", "preempted_ns"]]
