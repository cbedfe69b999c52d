"""`skel margin`'s predicted search (host/theory/margin.py): the largest factor before a flaw."""

from __future__ import annotations

from pathlib import Path

import pytest
from conftest import REPO, skel

from skeleton.host.sysfile.system import load, loads
from skeleton.host.theory.margin import Scope, margin, scaled

SERVO = REPO / "examples" / "servo.yaml"
HALF = """\
system: half
dpus: [{id: 1}]
processes:
  - {id: 1, name: a, dpu: 1, period_us: 10000, compute_us: 2000}
  - {id: 2, name: b, dpu: 1, period_us: 10000, compute_us: 3000}
"""
PACED = """\
system: paced
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: sample, bytes: 64}]
processes:
  - {id: 1, name: writer, dpu: 1, period_us: 10000, compute_us: 1000, outputs: [sample]}
  - {id: 2, name: reader, dpu: 2, period_us: 5000, compute_us: 1000, sync: data, inputs: [sample]}
"""


def test_a_dpu_at_half_load_has_a_compute_margin_of_exactly_two() -> None:
    found = margin(loads(HALF, Path("half.yaml")), "compute")
    assert found.factor == pytest.approx(2.0, rel=1e-6)
    assert found.breaks and "DPU 1" in found.breaks[0]


def test_servo_breaks_first_on_dpu_4_at_1_over_0_965_on_compute_and_rate() -> None:
    servo = load(SERVO)
    compute = margin(servo, "compute")
    assert compute.factor == pytest.approx(1 / 0.965, rel=1e-5)
    assert compute.breaks[0].startswith("DPU 4:")
    # every period divided by the factor: the 2.5 ms experiment's jam begins just under 5 ms x 0.965
    rate = margin(servo, "rate")
    assert rate.factor == pytest.approx(1 / 0.965, rel=1e-4) and rate.breaks[0].startswith("DPU 4:")
    # each DPU alone: its own load's reciprocal, DPU 3 sooner (its data wait counts in its frame)
    by_dpu = {d: margin(servo, "compute", Scope(dpu=d)).factor for d in (1, 2, 4)}
    assert by_dpu == pytest.approx({1: 1 / 0.903, 2: 1 / 0.734, 4: 1 / 0.965}, rel=1e-5)
    assert margin(servo, "compute", Scope(dpu=3)).factor < 1 / 0.86
    # SERVO gives no link a bandwidth: bytes never break it
    assert margin(servo, "bytes").factor is None


def test_a_reader_paced_by_a_slower_writer_is_named_not_counted() -> None:
    found = margin(loads(PACED, Path("paced.yaml")), "compute")
    assert any("reader is paced by writer" in line for line in found.paced)
    assert found.factor == pytest.approx(5.0, rel=1e-6)  # DPU 2 at 20 %: the load, not the pacing
    assert not any("reader" in line for line in found.breaks)


def test_a_scaled_system_changes_only_its_axis() -> None:
    servo = load(SERVO)
    faster = scaled(servo, "rate", 2.0)
    assert [p.period_us for p in faster.processes] == [p.period_us // 2 for p in servo.processes]
    assert [p.compute_us for p in faster.processes] == [p.compute_us for p in servo.processes]
    one = scaled(servo, "compute", 1.5, Scope(process="executor"))
    assert one.process("executor").compute_us == 5250 and one.process("trajectory").compute_us == 1200


def test_a_bad_scope_gets_one_line_and_exit_2(tmp_path: Path) -> None:
    done = skel("margin", str(SERVO), "--process", "nobody")
    assert done.returncode == 2 and done.stderr.strip().count("\n") == 0 and "nobody" in done.stderr
    done = skel("margin", str(SERVO), "--axis", "rate", "--dpu", "1")
    assert done.returncode == 2 and "compute axis" in done.stderr, done.stderr


def test_the_plot_marks_the_margin(tmp_path: Path) -> None:
    done = skel("margin", str(SERVO), "--plots", str(tmp_path / "plots"))
    assert done.returncode == 0, done.stderr
    png = tmp_path / "plots" / "margin-compute.png"
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 20_000


def test_a_hold_under_one_hyperperiod_is_refused_in_one_line() -> None:
    done = skel("margin", str(SERVO), "--measure", "--hold", "0")
    assert done.returncode == 2 and "--hold 0" in done.stderr and done.stderr.count("\n") == 1, done.stderr
