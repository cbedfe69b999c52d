"""What the report makes of a run's logic, on simulated time: a data wait the schedule plans,
rates that do not match, a reader starved of data. The real skel-dpu runs each system with
no platform beneath it, so each figure is the definition's, exactly."""

from __future__ import annotations

from pathlib import Path

from conftest import EXAMPLES, LOCKOUT_SYSTEM
from sim.test_executives import simulate

# A data reader waits 3 ms each cycle for its writer on another DPU, holding its cyclic DPU:
# the process after it starts at 4 ms by design (skel check predicts it so).
PLANNED_WAIT_SYSTEM = """\
system: planned_wait
dpus: [{id: 1, compute: sleep}, {id: 2, compute: sleep}]
buffers: [{id: 1, name: buf, bytes: 64}]
processes:
  - {id: 1, name: w, dpu: 1, period_us: 10000, compute_us: 3000, outputs: [buf]}
  - {id: 2, name: rd, dpu: 2, period_us: 10000, compute_us: 1000, sync: data, inputs: [buf], order: 1}
  - {id: 3, name: p2, dpu: 2, period_us: 10000, compute_us: 1000, order: 2}
run: {duration_s: 3, warmup_cycles: 5, late_pct: 20}
"""


def test_a_data_wait_the_design_plans_is_not_lateness(tmp_path: Path) -> None:
    """The schedule's start of a process after a data reader on the cyclic executive counts the
    reader's planned wait (the prediction's: its writer's end, sent as process_t.ready_us): p2
    after rd is on schedule at 4 ms, not late by the 3 ms wait in every cycle (it was: lateness
    p50 3.1 ms, late in 100 % of its cycles, while every figure was within its prediction)."""
    path = tmp_path / "planned_wait.yaml"
    path.write_text(PLANNED_WAIT_SYSTEM)
    report = simulate(tmp_path / "run", str(path))
    procs = {p["name"]: p for p in report["processes"]}
    exact = {"p50": 4000.0, "p99": 4000.0, "max": 4000.0}
    on_time = {"p50": 0.0, "p99": 0.0, "max": 0.0}
    assert procs["p2"]["latency_us"] == exact and procs["p2"]["lateness_us"] == on_time, procs["p2"]
    assert procs["rd"]["lateness_us"] == on_time, procs["rd"]  # its turn; it then waits, blocked
    assert all(p["late_unstalled"] == 0 and p["cycles"] == 295 for p in procs.values()), procs
    beside = {p["name"]: p["response_us"] for p in report["predicted"]["processes"]}
    assert beside["p2"] == {"predicted": 5000.0, "measured": 5000.0, "delta": 0.0, "outside": False}


def test_mismatched_rates_give_stale_and_dropped(tmp_path: Path) -> None:
    report = simulate(tmp_path / "run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--duration", "3",
                      "-s", "run.warmup_cycles=10")
    inputs = {p["name"]: p["inputs"][0] for p in report["processes"] if p["inputs"]}
    fast, slow = inputs["fast_reader"], inputs["slow_reader"]
    # A 10 ms writer read every 5 ms: new every other cycle, stale the others, none dropped.
    assert (fast["new"], fast["stale"], fast["dropped"]) == (290, 290, 0), fast
    # A 5 ms writer read every 10 ms: every read is new and skips one sequence.
    assert (slow["new"], slow["stale"], slow["dropped"]) == (290, 0, 290), slow


def test_lockout_of_a_data_synchronised_reader(tmp_path: Path) -> None:
    """Its writer sends every 100 ms, it may wait 5 of its 5 ms periods: its cycle 1 is locked
    out 30 ms into the run, naming the buffer and its writer, and stop_on ends the run."""
    path = tmp_path / "lockout.yaml"
    path.write_text(LOCKOUT_SYSTEM)
    report = simulate(tmp_path / "run", str(path))
    (fault,) = [f for f in report["faults"] if f["kind"] == "lockout"]
    assert (fault["process"], fault["buffer"], fault["writer"], fault["cycle"], fault["at_s"]) == (
        "hungry_reader", "slow_data", "slow_writer", 1, 0.03), fault
    assert fault["fatal"] and fault["detail"] == "waits on slow_data; not completed by 0.030 s"
    stopped = report["stopped"]
    assert stopped["command"] == "STOP" and stopped["planned_s"] == 3.0 and stopped["at_s"] < 3.0, stopped
