"""analysis/measure/predicted.py: the prediction beside the measurement, its deltas and the
tolerances that flag a measured value outside its prediction; on synthetic figures, then
on real runs (sanitizer DPUs, a private port): SERVO in sleep mode, and two spinning DPUs
pinned to one CPU, where the platform's cost is the point."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest
from analysis_synth import RUN_ID, batches, small_config, small_run, write_log
from conftest import HOST_EVENTS_SYSTEM
from rich.console import Console

from skeleton.analysis.measure.chains import ChainMetrics
from skeleton.analysis.measure.faults import Fault
from skeleton.analysis.measure.metrics import DpuMetrics, InputMetrics, ProcessMetrics
from skeleton.analysis.measure.predicted import PLATFORM, beside
from skeleton.analysis.measure.stats import LatencyUs
from skeleton.analysis.views.report import report_command
from skeleton.analysis.views.tables import predicted_tables
from skeleton.host.model import Expected
from skeleton.host.sysfile.system import load
from skeleton.host.theory.predict import predict
from skeleton.host.theory.predictor import predictor
from skelmsg.contract import CONFIG_CHANNEL, TIMING_CHANNEL


def _dpu(dpu_id: int, compute_pct: float) -> DpuMetrics:
    return DpuMetrics(dpu_id, [], 5.0, 5.0, compute_pct, 1.0, 1.0, 1.0, compute_pct, 0, 1000.0, 100,
                      compute_unstalled_pct=compute_pct)


def _process(name: str, p99_us: float, inputs: tuple[InputMetrics, ...] = ()) -> ProcessMetrics:
    return ProcessMetrics(1, name, 1, 5000, 100, 0, 0, LatencyUs(10, 20, 30), 1000.0, 100.0, 0, 0,
                          inputs=list(inputs), response_us=LatencyUs(p99_us / 2, p99_us, p99_us + 1))


PREDICTION = Expected.from_json({
    "dpus": [{"id": 1, "compute_pct": 90.0}, {"id": 2, "compute_pct": 75.0}, {"id": 3, "compute_pct": 50.0}],
    "processes": [
        {"name": "a", "response_us": 5000.0, "paced_by": None},
        {"name": "b", "response_us": 5000.0, "paced_by": None},
        {"name": "c", "response_us": 1000.0, "paced_by": "a"},
        {"name": "d", "response_us": None, "paced_by": None},
    ],
    "inputs": [{"reader": "b", "buffer": "slow", "writer": "a", "new": 0.21, "stale": 0.79, "dropped": 0.0},
               {"reader": "b", "buffer": "fast", "writer": "a", "new": 1.0, "stale": 0.0, "dropped": 3.76}],
    "chains": [{"name": "ab", "processes": ["a", "b"], "best_us": 1000.0, "worst_us": 9000.0}],
})


def test_each_rule_flags_only_beyond_its_tolerance() -> None:
    got = beside(PREDICTION, 4, 20, [_dpu(1, 91.9), _dpu(2, 77.5)],
                 [_process("a", 6100), _process("b", 5900, (InputMetrics("slow", 1, 30, 70, 0, 30),
                                                            InputMetrics("fast", 2, 100, 0, 380, 480))),
                  _process("c", 50000), _process("d", 90000)],
                 [ChainMetrics("ab", ["a", "b"], ["x"], LatencyUs(5000, 9900, 12000), 100, 0)])
    assert got.generation == 4
    # % compute: ±2 points either way; a DPU without figures is left out
    assert [(d.id, round(d.compute_pct.delta, 1), d.compute_pct.outside) for d in got.dpus] == [
        (1, 1.9, False), (2, 2.5, True)]
    # response: the p99 may pass the worst by late_pct (20 %) of the 5 ms period; a paced reader
    # waits for its writer (not compared), an unbounded worst bounds nothing
    assert {p.name: (p.response_us.delta, p.response_us.outside) for p in got.processes} == {
        "a": (1100, True), "b": (900, False), "c": (49000, False), "d": (None, False)}
    slow, fast = got.inputs
    assert (slow.new.measured, slow.new.outside, slow.stale.outside) == (0.3, True, True)
    assert (fast.dropped.measured, fast.dropped.outside) == (3.8, False)
    assert (got.chains[0].latency_us.delta, got.chains[0].latency_us.outside) == (900, False)
    assert got.outside == [
        f"DPU 2: % compute 77.5 measured against predicted 75.0 (+2.5, beyond ±2 points): {PLATFORM}",
        "a (DPU 1): response p99 6100 µs measured against the predicted worst 5000 µs (+1100 µs, beyond "
        f"late_pct (20 %) of the period): {PLATFORM}",
        f"b <- slow: new share 0.300 measured against predicted 0.210 (+0.090, beyond ±0.05): {PLATFORM}"]


def test_a_run_with_a_lost_dpu_or_a_fatal_fault_blames_that_not_the_platform() -> None:
    """The prediction leaves out a DPU that died and the design's own fatal faults: a figure
    outside it in such a run is put down to them (a walk-through's killed DPU read "the
    platform's own cost")."""
    figures = ([_dpu(2, 77.5)], [_process("a", 6100)], [])
    lost = Fault(kind="dpu_lost", dpu=3, detail="not heard for 2.36 s from 1.49 s into the run")
    jam = Fault(kind="jam", process=1, dpu=1, detail="circular wait")
    stall = Fault(kind="stall", dpu=1, detail="host h: DPU 1 could not run")
    for faults, cause in (((lost, jam), "DPU 3 lost during the run (its fault above), not only the platform"),
                          ((jam,), "the design's own fatal faults above, not only the platform"),
                          ((stall,), PLATFORM), ((), PLATFORM)):
        got = beside(PREDICTION, 4, 20, *figures, faults)
        assert jam.fatal and not stall.fatal and got.cause == cause
        assert len(got.outside) == 2 and all(line.endswith(f": {cause}") for line in got.outside), got.outside


def test_what_a_host_events_rate_decides_is_never_outside(tmp_path: Path) -> None:
    """The host sent a handful of events: what follows from their rate was unknown, so
    however far the run is from one a period, none of it is the platform's cost."""
    path = tmp_path / "host.yaml"
    path.write_text(HOST_EVENTS_SYSTEM)
    prediction = Expected.from_json(predict(load(path)).to_json())
    got = beside(prediction, 1, 20, [_dpu(1, 0.4), _dpu(2, 31.0), _dpu(3, 0.2)],
                 [_process("on_demand", 100, (InputMetrics("tick", 2, 3, 3, 900, 1000),)),
                  _process("listener", 600, (InputMetrics("knock", 1, 5, 995, 0, 5),)),
                  _process("waiter", 900_000, (InputMetrics("knock", 1, 5, 0, 0, 5),))], [])
    assert [(d.id, d.compute_pct.predicted, d.compute_pct.outside) for d in got.dpus] == [
        (1, None, False), (2, 20.0, True), (3, None, False)]
    on_demand, listener, waiter = got.inputs
    assert (on_demand.new.predicted, on_demand.new.outside) == (1.0, True)  # known: ticker is fast enough
    assert (on_demand.dropped.predicted, on_demand.dropped.outside) == (None, False)
    for unknown in (listener, waiter):
        assert [(b.predicted, b.outside) for b in (unknown.new, unknown.stale, unknown.dropped)] == [
            (None, False)] * 3
    # waiter waited for on_demand's knock inside its response: not judged
    assert next(p for p in got.processes if p.name == "waiter").response_us.outside is False
    assert got.outside == [
        f"DPU 2: % compute 31.0 measured against predicted 20.0 (+11.0, beyond ±2 points): {PLATFORM}",
        f"on_demand <- tick: new share 0.500 measured against predicted 1.000 (-0.500, beyond ±0.05): "
        f"{PLATFORM}"]
    console = Console(file=io.StringIO(), width=140, record=True, color_system=None)
    for table in predicted_tables(got):
        console.print(table)
    text = console.export_text()
    assert "│   1 │ unknown │    0.4 │" in text, text
    assert "│ listener <- knock (on_demand) │ unknown │" in text, text


@pytest.mark.parametrize(("source", "why"), [
    ("system: small\n", "{path}: "),  # what the synthetic config carries: no DPU, no process
    ("", "the run's configuration carries no system file"),
])
def test_a_run_whose_system_file_cannot_be_predicted_says_why(
        tmp_path: Path, capsys: pytest.CaptureFixture[str], source: str, why: str) -> None:
    dpu1, dpu2 = small_run()
    config = small_config()
    config.source = source
    log = write_log(tmp_path / "run.lcm", [(CONFIG_CHANNEL, config)] + [
        (TIMING_CHANNEL, t) for t in batches(1, dpu1, 4) + batches(2, dpu2, 2)])
    assert report_command(log, as_json=True, run_id=RUN_ID, predictor=predictor(tmp_path / "s.yaml")) == 0
    out = capsys.readouterr()
    assert json.loads(out.out)["predicted"] is None
    assert "run.lcm: no prediction: " + why.format(path=tmp_path / "s.yaml") in out.err, out.err
