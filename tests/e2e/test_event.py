"""Processes that await an external event (`sync: event`): real DPUs, real generators, the
host's `skel event`, and processes that emit events, held to what the process model says:
one cycle per event, queues that keep the newest or the oldest and count what they drop,
every generated instant repeated exactly by the same seed."""

from __future__ import annotations

import time
from pathlib import Path

import lcm
import numpy as np
import pandas as pd
import pytest
from conftest import EXAMPLES, skel, skel_background

import skeleton
import skelmsg
from skeleton.host.live.control import Control
from skelmsg import contract

pytestmark = pytest.mark.timing  # judges the DPUs' timing: tests/steal.py

MS = 1_000_000  # ns


def _write(tmp_path: Path, name: str, text: str) -> Path:
    path = tmp_path / f"{name}.yaml"
    path.write_text(text)
    return path


def _events(out: Path, name: str) -> list[skelmsg.event_t]:
    """The events NAME of the run in OUT's log, as the logger recorded them."""
    log = lcm.EventLog(str(out / "run.lcm"), "r")
    channel = contract.EVENT_CHANNEL_PREFIX + name
    return [skelmsg.event_t.decode(e.data) for e in log if e.channel == channel]


def _cycles(out: Path) -> pd.DataFrame:
    return skeleton.load_run(out).timing.to_pandas()


# Both ways of the tasking executive: its own schedule (sleep), SCHED_FIFO kernel threads (cpu).
MODES = pytest.mark.parametrize("compute", ["sleep", "cpu"])

# One tasking DPU, two processes awaiting the same bursts of 5 events 0.5 ms apart. Each may
# run once per 50 ms, so a burst leaves 4 events waiting: `queue: 1` keeps only the newest
# (3 dropped, and its second cycle handles the burst's last event), `queue: 2` keeps the two
# oldest (2 dropped, events handled in order).
BURSTS = """\
system: bursts
dpus: [{id: 1, executive: threads, compute: COMPUTE}]
processes:
  - {id: 1, name: newest, dpu: 1, period_us: 50000, compute_us: 200, sync: event, event: burst, queue: 1}
  - {id: 2, name: oldest, dpu: 1, period_us: 50000, compute_us: 200, sync: event, event: burst, queue: 2}
events:
  - {name: burst, kind: bursts, dpu: 1, period_us: 200000, count: 5, spacing_us: 500}
run: {duration_s: 2.1, warmup_cycles: 0, lockout_cycles: 1000, stop_on: []}
"""


def test_kernel_threads_keep_the_newest_or_the_oldest_event_and_count_what_they_drop(tmp_path: Path,
                                                                                   url: str) -> None:
    """In compute mode cpu the kernel schedules the processes' threads (threads.c), a way of
    its own to take a queue's events: it runs on real time only. The executive's own schedule
    (sleep) takes them as tests/sim holds it to, job by job on virtual time."""
    out = tmp_path / "run"
    path = _write(tmp_path, "bursts", BURSTS.replace("COMPUTE", "cpu"))
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    cycles = _cycles(out)
    sent = _events(out, "burst")
    assert len(sent) == 5 * 10, len(sent)  # bursts at 0.2 s .. 2.0 s, generated on time
    # Which events of its burst each kept. The generator's instants are in the log (one DPU:
    # one clock), and an event cannot arrive before its instant; both processes see the same
    # arrival stamp for the same event. A burst's last event comes 2 ms after its first.
    starts = np.sort([e.sent_ns for e in sent])[::5]
    got = cycles[cycles.event_ns >= 0].copy()
    got["burst"] = np.searchsorted(starts, got.event_ns, side="right") - 1
    kept = {}
    # The DPU's stalls (a stop of its thread, a wake-up later than the processor was its: on
    # CI's VM up to 17 ms that steal does not show, in 0 to 7 of the 9 bursts of a run) are the
    # platform's: a burst whose jobs recorded over 1 ms of them is not judged on time, and at
    # least 3 bursts are.
    stalled = set(got.burst[got.stall_ns > 1_000_000])
    # The generator's thread held up past a burst's 2 ms (the platform: CI once 2.4 ms, no stall
    # the DPU saw) delivers all of it before the first job runs, and each queue drops one more:
    # such a burst's counts are not judged either (its first event reached the jobs that late).
    arrived = got.groupby("burst").event_ns.min()
    held_up = {int(b) for b, at in arrived.items() if b < len(starts) and at - starts[b] > 2 * MS}
    assert len((stalled | held_up) - {9}) <= 6, (held_up, got[got.stall_ns > 1_000_000][
        ["process", "cycle", "stall_ns"]])
    for name, handled, dropped in (("newest", 2, 3), ("oldest", 3, 2)):
        mine = got[(got.process_name == name) & (got.burst < 9)]  # the last burst may be cut off
        assert mine.burst.nunique() == 9, mine
        for b, burst in mine.groupby("burst"):
            if b in held_up:
                continue
            assert len(burst) == handled, (name, b, burst)
            assert burst.event_dropped.sum() == dropped, (name, b, burst)
            kept[name, b] = burst.event_ns.to_numpy()
            if b in stalled:
                continue
            # The first runs at once; the next waits for its period, 50 ms after the first's
            # release (the period spaces releases: a first start late by a stall, 1.3 ms once in
            # CI, does not push the next one back; the burst's events themselves may come late
            # from a loaded generator thread).
            latency = (burst.start_ns - burst.event_ns).to_numpy() / MS
            starts_ms = burst.start_ns.to_numpy() / MS
            first_release_ms = burst.release_ns.to_numpy()[0] / MS
            assert latency[0] < 5, (name, b, latency)
            assert 49 < starts_ms[1] - first_release_ms < 55, (name, b, starts_ms - first_release_ms)
    for b in sorted(set(range(9)) - held_up):
        newest, oldest = kept["newest", b], kept["oldest", b]
        assert newest[1] >= starts[b] + 2 * MS, (b, newest - starts[b])  # the newest: the burst's last
        assert (np.diff(oldest) >= 0).all() and oldest[-1] <= newest[1], (b, oldest, newest)  # the oldest,
        # in order (events a stalled generator sent together may share a microsecond stamp: CI
        # once saw a whole burst under one)
        assert oldest[0] <= newest[0], (b, oldest, newest)
    report = skel("report", str(out), "--json")
    assert report.returncode == 0, report.stderr
    assert "per process awaiting an event" in skel("report", str(out), "--all").stdout


# A Poisson sensor on a cyclic DPU fires `fresh` at each cycle's end; a reaction on a tasking
# DPU awaits it with the highest priority, preempting the servo loop there.
CHAIN = """\
system: chain
dpus: [{id: 1}, {id: 2, executive: threads, compute: COMPUTE}]
buffers: [{id: 1, name: frame, bytes: 64}]
processes:
  - {id: 1, name: sensor, dpu: 1, period_us: 2000, compute_us: 300, sync: event, event: pulse, queue: 8,
     outputs: [frame], emits: [fresh]}
  - {id: 2, name: servo, dpu: 2, period_us: 5000, compute_us: 1000, inputs: [frame]}
  - {id: 3, name: react, dpu: 2, period_us: 1000, compute_us: 100, sync: event, event: fresh, queue: 64}
events:
  - {name: pulse, kind: poisson, dpu: 1, rate_hz: 200}
run: {duration_s: 2, warmup_cycles: 10, lockout_cycles: 100, seed: SEED}
"""


@MODES
def test_generated_and_emitted_events_each_run_one_cycle_drawn_as_the_simulation_draws_them(
        tmp_path: Path, url: str, compute: str) -> None:
    out = tmp_path / "a"
    path = _write(tmp_path, "a", CHAIN.replace("SEED", "7").replace("COMPUTE", compute))
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode in (0, 1), run.stdout + run.stderr
    cycles = _cycles(out)
    pulses = _events(out, "pulse")
    sensor = cycles[cycles.process_name == "sensor"]
    # One cycle per pulse: each handled or dropped, at most a queue's worth left at the end.
    accounted = int((sensor.event_ns >= 0).sum() + sensor.event_dropped.sum())
    assert 0 <= len(pulses) - accounted <= 8, (len(pulses), accounted)
    assert len(pulses) > 200  # 200 Hz for 2 s
    # The cyclic executive looks at the queue once per period: an event waits up to one.
    assert (sensor.start_ns >= sensor.event_ns).all()
    assert np.median(sensor.start_ns - sensor.event_ns) < 3 * MS
    # Each sensor cycle's end fired `fresh`, and the reaction ran once for each.
    fresh = _events(out, "fresh")
    completed = sensor[sensor.completed]
    assert abs(len(fresh) - len(completed)) <= 1, (len(fresh), len(completed))
    assert sorted(e.seq for e in fresh) == list(range(len(fresh)))
    react = cycles[(cycles.process_name == "react") & cycles.completed]
    assert len(fresh) - 2 <= len(react) <= len(fresh), (len(react), len(fresh))
    assert react.event_dropped.sum() == 0
    # The tasking executive releases it at the event, above the servo loop: it waits for no frame.
    assert np.median(react.start_ns - react.event_ns) < 1 * MS
    report = skeleton.load_run(out).report
    events = next(p.events for p in report.processes if p.name == "react")
    assert events is not None and events.event == "fresh" and events.handled > 0

    # The generator draws its instants from the seed alone: the simulation of the same file
    # draws the same ones, to the nanosecond, on virtual time (tests/sim: another seed, others).
    simulated = tmp_path / "simulated"
    done = skel("simulate", str(path), "--out", str(simulated))
    assert done.returncode in (0, 1), done.stdout + done.stderr
    gaps = np.diff([e.sent_ns for e in pulses])
    again = np.diff([e.sent_ns for e in _events(simulated, "pulse")])
    n = min(len(gaps), len(again))
    assert n > 200, (len(gaps), len(again))
    assert (gaps[:n] == again[:n]).all()


HOST = """\
system: host_events
dpus: [{id: 1}]
processes:
  - {id: 1, name: on_demand, dpu: 1, period_us: 1000, compute_us: 100, sync: event, event: go, queue: 64}
  - {id: 2, name: ticker, dpu: 1, period_us: 1000, compute_us: 100}
events:
  - {name: go, kind: host}
run: {duration_s: 6, warmup_cycles: 0, stop_on: []}
"""


def test_the_host_sends_events_with_skel_event(tmp_path: Path, url: str) -> None:
    out = tmp_path / "run"
    run = skel_background("run", str(_write(tmp_path, "host", HOST)), "--spawn", "--url", url,
                          "--out", str(out))
    control = Control(url)
    try:
        running = control.wait_for(lambda: 1 in control.dpus and control.dpus[1].state == "running", 30)
        assert running, run.output
    finally:
        control.close()
    sent = skel("event", "go", "--count", "20", "--rate", "100", "--url", url)
    assert sent.returncode == 0 and "sent 20 events go" in sent.stdout, sent.stdout + sent.stderr
    assert run.wait(60) in (0, 1), run.output
    cycles = _cycles(out)
    mine = cycles[cycles.process_name == "on_demand"]
    assert len(mine) == 20, mine
    assert (mine.event_ns >= 0).all() and mine.event_dropped.sum() == 0
    assert sorted(mine.cycle) == list(range(20))  # its cycles count its events
    assert skel("event", "9x", "--url", url).returncode == 2


# DPUs that run on host-sent events alone, one per executive, with a warm-up: events sent
# long after it must all be measured.
EVENTS_ONLY = """\
system: events_only
dpus: [{id: 1}, {id: 2, executive: threads}]
processes:
  - {id: 1, name: on_cyclic, dpu: 1, period_us: 5000, compute_us: 200, sync: event, event: go, queue: 64}
  - {id: 2, name: on_threads, dpu: 2, period_us: 5000, compute_us: 200, sync: event, event: go, queue: 64}
events:
  - {name: go, kind: host}
run: {duration_s: 5, warmup_cycles: 20, stop_on: []}
"""


def test_a_dpu_of_events_only_measures_from_its_runs_warm_up_not_its_first_event(tmp_path: Path,
                                                                                   url: str) -> None:
    """Its cycles count events, not periods: the window opens warmup_cycles periods after the
    run began, as the DPU's own does, so every event sent after that is measured, and the
    DPU's running sums agree with the records'."""
    out = tmp_path / "run"
    run = skel_background("run", str(_write(tmp_path, "events_only", EVENTS_ONLY)), "--spawn", "--url", url,
                          "--out", str(out))  # fmt: skip
    control = Control(url)
    try:
        running = control.wait_for(lambda: all(d in control.dpus and control.dpus[d].state == "running"
                                                for d in (1, 2)), 30)  # fmt: skip
        assert running, run.output
    finally:
        control.close()
    time.sleep(1.0)  # the warm-up (20 x 5 ms) long over
    sent = skel("event", "go", "--count", "20", "--rate", "50", "--url", url)
    assert sent.returncode == 0, sent.stdout + sent.stderr
    assert run.wait(60) in (0, 1), run.output
    report = skeleton.load_run(out).report
    for name in ("on_cyclic", "on_threads"):
        proc = next(p for p in report.processes if p.name == name)
        assert proc.events is not None and proc.events.handled == 20, (name, proc.events)
    for check in report.cross_check:
        dpu_ms, records_ms = check["compute_ms"]
        assert records_ms == pytest.approx(dpu_ms, rel=0.05, abs=0.05), check


def test_the_event_driven_servo_example_runs(tmp_path: Path, url: str) -> None:
    """examples/servo-events.yaml: a Poisson contact sensor feeding SERVO's force control."""
    out = tmp_path / "run"
    run = skel("run", str(EXAMPLES / "servo-events.yaml"), "--spawn", "--url", url, "--cycles", "300",
               "-s", "run.warmup_cycles=10", "--out", str(out), "--all")
    assert run.returncode in (0, 3), run.stdout + run.stderr  # 3: a busy machine's lockout
    assert "per process awaiting an event" in run.stdout
    report = skeleton.load_run(out).report
    sensor = next(p for p in report.processes if p.name == "contact_sensor")
    assert sensor.events is not None and sensor.events.handled > 50, sensor.events
    force = next(p for p in report.processes if p.name == "force_control")
    contact = next(i for i in force.inputs if i.buffer == "contact")
    assert contact.new > 0 and contact.stale > 0, contact  # events come at 200 Hz, it reads at 200 Hz
