"""tests/unit/test_predict.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from conftest import EXAMPLES, skel
from randsys import random_system

from skeleton.host.sysfile.system import load
from skeleton.host.theory.predict import predict

DEADLOCK = """\
system: deadlock
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: ping, bytes: 64}, {id: 2, name: pong, bytes: 64},
          {id: 3, name: tick, bytes: 8}]
processes:
  - {id: 1, name: left, dpu: 1, period_us: 10000, compute_us: 300, sync: data, inputs: [pong, tick],
     required: [pong], outputs: [ping]}
  - {id: 2, name: right, dpu: 2, period_us: 10000, compute_us: 300, sync: data, inputs: [ping],
     outputs: [pong]}
  - {id: 3, name: clock, dpu: 2, period_us: 10000, compute_us: 300, outputs: [tick]}
run: {duration_s: 2, warmup_cycles: 0, lockout_cycles: 10, stop_on: [lockout]}
"""


def _system(tmp_path: Path, text: str, name: str = "s.yaml"):  # type: ignore[no-untyped-def]
    path = tmp_path / name
    path.write_text(text)
    return load(path)


def _refused(tmp_path: Path, text: str) -> tuple[Path, list[str]]:
    """The file of TEXT and what `skel check` says of it: bad input (exit 2), refused by
    `skel check --json` and by `skel run` (which names --no-check) too."""
    path = tmp_path / "refused.yaml"
    path.write_text(text)
    done = skel("check", str(path))
    assert done.returncode == 2
    assert skel("check", str(path), "--json").returncode == 2
    refused = skel("run", str(path), "--spawn")
    assert refused.returncode == 2 and "--no-check" in refused.stderr
    return path, done.stderr.splitlines()


def test_deadlock_is_refused_with_the_cycle_named(tmp_path: Path) -> None:
    path, said = _refused(tmp_path, DEADLOCK)
    assert said == [
        f"{path}: processes.left.required: data-wait deadlock: left -> right -> left can never start "
        "(left waits for pong from right; right waits for ping from left); make one of them sync: "
        "periodic or take the buffer out of its `required`"]


def test_deadlock_run_with_no_check_locks_out_as_predicted(tmp_path: Path, url: str) -> None:
    path = tmp_path / "deadlock.yaml"
    path.write_text(DEADLOCK)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--no-check", "--url", url, "--out", str(out))
    assert run.returncode == 3, run.stdout + run.stderr
    report = json.loads((out / "report.json").read_text())
    locked = {f["process"] for f in report["faults"] if f["kind"] == "lockout"}
    assert {"left", "right"} <= locked, report["faults"]


HELD = """\
system: held
dpus: [{id: 1}]
buffers: [{id: 1, name: sample, bytes: 64}]
processes:
  - {id: 1, name: reader, dpu: 1, period_us: 10000, compute_us: 300, sync: data, inputs: [sample]}
  - {id: 2, name: writer, dpu: 1, period_us: 10000, compute_us: 300, outputs: [sample]}
run: {duration_s: 2, warmup_cycles: 0, lockout_cycles: 10, stop_on: [lockout]}
"""


def test_a_data_reader_before_its_writer_on_one_cyclic_dpu_is_refused(tmp_path: Path) -> None:
    """Its wait holds the DPU's one thread, so the writer after it in the first minor cycle
    never runs (the run below: both lock out at cycle 0, a circular wait); `skel check` said
    it was valid, with no warning."""
    path, said = _refused(tmp_path, HELD)
    assert said == [
        f"{path}: processes.reader.required: data-wait deadlock on DPU 1's cyclic executive: reader -> "
        "writer -> reader (reader waits for sample from writer; writer runs after it in the DPU's order, "
        "and reader's wait holds the DPU, so writer never runs: both lock out at cycle 0); give writer "
        "an order before reader, move one of them to another DPU or take sample out of reader's "
        "`required`"]
    # a slower writer before it has written nothing new by its second cycle (run: cycle 1)
    slower = predict(_system(tmp_path, HELD.replace("period_us: 10000, compute_us: 300, outputs",
                                                    "period_us: 20000, compute_us: 300, order: 1, outputs")))
    assert [e.problem.split(" (")[1].split(";")[1] for e in slower.errors] == [
        " writer runs every 20 ms to its 10 ms, so its cycle 1 finds no new sample, and reader's wait "
        "holds the DPU, so writer never runs: both lock out at cycle 1)"]
    assert {p.rate_hz for p in slower.processes} == {0}
    # a cycle of data readers on one DPU is named once, as a cycle
    one_dpu = predict(_system(tmp_path, DEADLOCK.replace("dpu: 2", "dpu: 1")))
    assert [e.problem.split(":")[0] for e in one_dpu.errors] == ["data-wait deadlock"]
    # the writer first, or a tasking processor that runs it while the reader waits: no deadlock
    for fine in (HELD.replace("outputs: [sample]}", "outputs: [sample], order: 1}"),
                 HELD.replace("dpus: [{id: 1}]", "dpus: [{id: 1, executive: threads}]")):
        pred = predict(_system(tmp_path, fine))
        assert pred.errors == () and pred.schedulable and pred.process("reader").rate_hz == 100


def test_a_data_reader_before_its_writer_run_with_no_check_locks_out_as_predicted(
        tmp_path: Path, url: str) -> None:
    path = tmp_path / "held.yaml"
    path.write_text(HELD)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--no-check", "--url", url, "--out", str(out))
    assert run.returncode == 3, run.stdout + run.stderr
    faults = json.loads((out / "report.json").read_text())["faults"]
    assert {(f["kind"], f["process"], f["cycle"]) for f in faults if f["kind"] in ("lockout", "jam")} == {
        ("lockout", "reader", 0), ("lockout", "writer", 0), ("jam", "reader", 0)}, faults


def _measured_vs_predicted(tmp_path: Path, url: str, path: Path,
                           *args: str) -> list[tuple[int, float, float]]:
    out = tmp_path / f"run-{path.stem}"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out), *args)
    assert run.returncode == 0, run.stdout + run.stderr
    pred = predict(load(path))
    return [(d["id"], d["compute_unstalled_pct"], pred.dpu(d["id"]).compute_pct)
            for d in json.loads((out / "report.json").read_text())["dpus"]]


@pytest.mark.timing  # judges % compute against the prediction: tests/steal.py
def test_servo_measured_compute_is_the_prediction(tmp_path: Path, url: str) -> None:
    rows = _measured_vs_predicted(tmp_path, url, EXAMPLES / "servo.yaml", "--cycles", "800",
                                  "-s", "run.warmup_cycles=20", "-s", "run.lockout_cycles=20")
    for dpu, measured, predicted in rows:
        assert measured == pytest.approx(predicted, abs=2.0), (dpu, measured, predicted)


@pytest.mark.timing
@pytest.mark.parametrize(("seed", "executive"), [(21, "cyclic"), (22, "threads"), (23, "cyclic")])
def test_random_systems_measure_what_is_predicted(tmp_path: Path, url: str, seed: int,
                                                 executive: str) -> None:
    text, _ = random_system(seed, executive=executive)
    path = tmp_path / f"random-{seed}.yaml"
    path.write_text(text)
    for dpu, measured, predicted in _measured_vs_predicted(tmp_path, url, path):
        assert measured == pytest.approx(predicted, abs=2.0), (seed, dpu, measured, predicted)
