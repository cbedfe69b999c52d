"""host/cli/check.py: `skel check`, the static view of a system file."""

from __future__ import annotations

import io
import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import pytest

from skeleton.host.cli.check import check
from skeleton.host.live import preflight

EXAMPLES = Path(__file__).resolve().parents[2] / "examples"
SERVO = EXAMPLES / "servo.yaml"




def run_json(path: Path, overrides: tuple[str, ...] = ()) -> dict[str, Any]:
    out = io.StringIO()
    assert check(path, overrides, as_json=True, out=out) == 0
    result: dict[str, Any] = json.loads(out.getvalue())
    return result


def test_table(capsys: pytest.CaptureFixture[str]) -> None:
    out = io.StringIO()
    assert check(SERVO, out=out) == 0
    text = out.getvalue()
    assert "system servo" in text
    for needle in ("trajectory, forward_kinematics", "90.3", "73.4", "86.0", "96.5", "23.8",
                   "valid, no warnings"):
        assert needle in text
    assert capsys.readouterr().err == ""


def test_json_servo() -> None:
    result = run_json(SERVO)
    assert result["system"] == "servo"
    assert result["warnings"] == []
    assert [(d["id"], d["host"], d["minor_cycle_ms"], d["static_load_pct"]) for d in result["dpus"]] == [
        (1, "localhost", 5.0, 90.3), (2, "localhost", 5.0, 73.4), (3, "localhost", 5.0, 86.0),
        (4, "localhost", 23.8, 96.5)]
    assert result["dpus"][1]["processes"] == ["joint_sensors", "executor"]


def test_overload_warnings_at_2_5_ms() -> None:
    result = run_json(EXAMPLES / "servo-2.5ms.yaml")
    assert [d["static_load_pct"] > 100 for d in result["dpus"]] == [True, True, True, False]
    overrun = "exceeds 100 %: it will overrun every cycle and fall"
    assert [w.split(";")[0] for w in result["warnings"]] == [
        f"DPU 1: static load 180.6 % {overrun} 45 % of the time behind",
        f"DPU 2: static load 146.8 % {overrun} 32 % of the time behind",
        f"DPU 3: static load 172.0 % {overrun} 42 % of the time behind",
        "jacobian_transpose (sync: data, 400 Hz) is paced by joint_sensors: it will run at 200 Hz",
    ]


def test_overload_warning_in_table() -> None:
    out = io.StringIO()
    assert check(EXAMPLES / "servo-2.5ms.yaml", out=out) == 0
    assert "WARN DPU 1: static load 180.6 % exceeds 100 %" in out.getvalue()


def test_more_busy_dpus_than_cores(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(preflight.os, "cpu_count", lambda: 2)
    busy = ("dpu.1.compute=cpu", "dpu.2.compute=wall", "dpu.3.compute=work")
    assert run_json(SERVO, busy)["warnings"] == [
        "host localhost: 3 busy DPUs (1, 2, 3) compute in cpu/wall/work mode but this machine has 2 cores: "
        "they will preempt each other; use compute: sleep or fewer DPUs"]
    # sleep mode models a dedicated processor: it needs no core, whatever the count
    monkeypatch.setattr(preflight.os, "cpu_count", lambda: 1)
    assert run_json(SERVO)["warnings"] == []


def test_pinned_dpus_sharing_a_core(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(preflight.os, "cpu_count", lambda: 8)
    pinned = ("dpu.1.compute=cpu", "dpu.2.compute=cpu", "dpu.1.cpu=1", "dpu.2.cpu=1")
    assert run_json(SERVO, pinned)["warnings"] == ["DPU 2: pinned to cpu 1 like DPU 1: they share one core"]


def test_remote_hosts_are_not_counted(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(preflight.os, "cpu_count", lambda: 1)
    remote = ("dpu.1.compute=cpu", "dpu.2.compute=cpu", "dpu.1.host=lab-a", "dpu.2.host=lab-a")
    assert run_json(SERVO, remote)["warnings"] == []


def test_warmup_longer_than_the_run() -> None:
    warnings = run_json(SERVO, ("run.cycles=200",))["warnings"]   # 1 s; DPU 4 warms up 2.38 s
    assert warnings[0] == ("process dynamics: its warm-up (100 cycles of 23.8 ms = 2.38 s) is not shorter "
                           "than the run (1 s): none of its cycles would be measured")
    assert len(warnings) == 3


def test_invalid_file(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(SERVO.read_text().replace("period_us: 23800", "period_us: -5", 1))
    out = io.StringIO()
    assert check(path, out=out) == 2
    assert out.getvalue() == ""
    assert capsys.readouterr().err == (
        f"{path}: processes.dynamics.period_us: must be a positive number of microseconds, got -5\n")


def test_bad_override(capsys: pytest.CaptureFixture[str]) -> None:
    assert check(SERVO, ["process.nope.compute_us=1"], out=io.StringIO()) == 2
    assert capsys.readouterr().err == f"{SERVO}: -s process.nope.compute_us=1: no process named 'nope'\n"


def test_error_is_one_line_without_a_traceback(tmp_path: Path) -> None:
    """Outside pytest too: a fresh interpreter prints the one line and exits 2."""
    path = tmp_path / "bad.yaml"
    path.write_text("system: x\ndpus: [{id: 1}]\nprocesses:\n  - {id: 1, name: p, dpu: 1, period_us: 5000, "
                    "compute_us: 10, sync: dat}\n")
    code = "import sys; from skeleton.host.cli.check import check; sys.exit(check(sys.argv[1]))"
    done = subprocess.run([sys.executable, "-c", code, str(path)], capture_output=True, text=True, timeout=60)
    assert done.returncode == 2
    assert done.stdout == ""
    assert done.stderr == (f"{path}: processes.p.sync: must be one of 'periodic', 'data' or 'event', "
                           "got 'dat'\n")


@pytest.mark.parametrize(("override", "line"), [
    ("link.bus.per_message_us=-1", "links.bus.per_message_us: must be a cost from 0 to 1e+06, got -1"),
    ("link.bus.preset=token-ring",
     "links.bus.preset: no preset 'token-ring'; presets: vme, can-1m, ethernet-100m"),
])
def test_a_bad_link_cost_is_one_line_and_exit_2(override: str, line: str,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert check(SERVO, [override], out=io.StringIO()) == 2
    assert capsys.readouterr().err == f"{SERVO}: {line} (set by -s {override})\n"


def test_the_costs_a_link_charges_are_predicted_and_an_overload_they_make_is_flagged() -> None:
    """examples/servo-vme.yaml: the fitted VME bus's costs (docs/explanation/paper.md)."""
    result = run_json(EXAMPLES / "servo-vme.yaml")
    dpus = result["prediction"]["dpus"]
    assert [d["communicate_pct"] for d in dpus] == [9.491, 20.59, 9.341, 4.768]
    assert [d["compute_pct"] for d in dpus] == [90.3, 73.4, 86.0, 95.232]  # DPU 4: a share of its time
    assert [w.split(":")[0] for w in result["warnings"]] == ["DPU 3", "DPU 4"]
    assert "static load 101.3 % exceeds 100 %" in result["warnings"][1]
    out = io.StringIO()
    assert check(EXAMPLES / "servo-vme.yaml", out=out) == 0
    assert out.getvalue().count("communicate") == 2  # the DPUs' column and the processes' (wrapped)
