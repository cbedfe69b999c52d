"""tests/steal.py reads the platform's evidence from the DPUs' own logs: the lines it parses are
made here from the format strings in dpu/, so a reworded log line fails here, not silently there."""

from __future__ import annotations

import json
import re
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import steal
from steal import WorkSpeed, work_speed

DPU_SOURCE = Path(__file__).resolve().parents[2] / "dpu"


def _c_format(file: str, containing: str) -> str:
    """The C string literal (adjacent literals joined) of the log_line call in dpu/FILE whose
    format contains CONTAINING."""
    for call in re.finditer(r'log_line\(((?:\s*"(?:[^"\\]|\\.)*")+)', (DPU_SOURCE / file).read_text()):
        text = "".join(re.findall(r'"((?:[^"\\]|\\.)*)"', call.group(1)))
        if containing in text:
            return text.replace("%lld", "%d")
    raise AssertionError(f"no log_line in dpu/{file} says {containing!r}")


def _drift_line(at: str, pct: float) -> str:
    fmt = _c_format("executive.c", "the WORK kernel runs")
    slower = pct > 0
    return "skel-dpu[1]: " + fmt % (1, at, abs(pct), "slower" if slower else "faster",
                                    "longer" if slower else "less")


def _armed_line(run_id: int) -> str:
    return "skel-dpu[1]: " + _c_format("command.c", "armed") % (1, run_id, 499.5, 2.0)


def test_the_work_speed_is_as_far_off_as_logged_and_moved_each_runs_end_less_its_start(
        tmp_path: Path) -> None:
    (tmp_path / "run").mkdir()
    log = tmp_path / "run" / "dpu1.log"
    log.write_text("\n".join([
        _armed_line(1), _drift_line("start", 4.1), _drift_line("end", 2.8),     # moved 1.3
        _armed_line(2), _drift_line("start", 2.5),                              # end within 2 %: 2.5
        _armed_line(3), _drift_line("end", -3.0),   # not paired with run 2's start: 3.0
    ]) + "\n")
    assert work_speed(tmp_path) == WorkSpeed(off=4.1, moved=3.0)
    with log.open("a") as f:
        f.write("\n".join([_armed_line(4), _drift_line("start", 97.5), _drift_line("end", -10.0)]) + "\n")
    assert work_speed(tmp_path) == WorkSpeed(off=97.5, moved=107.5)


def test_a_run_without_drift_lines_moved_nothing(tmp_path: Path) -> None:
    (tmp_path / "dpu2.log").write_text(_armed_line(7) + "\n")
    assert work_speed(tmp_path) == WorkSpeed(off=0.0, moved=0.0)


def _attempt_with_steal(root: Path) -> steal.Attempt:
    """An attempt during which the hypervisor took every CPU: the platform's evidence at its most."""
    return steal.Attempt("t::x", time.monotonic() - 1.0, steal.stolen_ns() - 10 ** 10, root)


def test_an_attempt_whose_dpu_wrote_a_sanitizer_report_is_never_run_again(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch) -> None:
    # the attempt's logs outside this test's own tmp_path, which conftest judges after the test
    root = tmp_path_factory.mktemp("attempt")
    monkeypatch.setattr(steal, "_current", _attempt_with_steal(root))
    monkeypatch.setattr(steal, "_reattempted", [])
    monkeypatch.setattr(steal, "_reattempted_tests", set())
    log = root / "dpu-logs" / "dpu1.log"
    log.parent.mkdir()
    log.write_text("skel-dpu[1]: run 1 started\n")
    assert steal.platform_took_the_cpus(AssertionError("late"))       # the platform's, another attempt
    log.write_text("==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x6020\n")
    assert not steal.platform_took_the_cpus(AssertionError("late"))   # ours, whatever was stolen


def _finish(monkeypatch: pytest.MonkeyPatch, evidence: Path, reattempted: int, inconclusive: int) -> int:
    monkeypatch.setattr(steal, "EVIDENCE_FILE", evidence)
    monkeypatch.setattr(steal, "_reattempted_tests", {f"t::{i}" for i in range(reattempted)})
    monkeypatch.setattr(steal, "_inconclusive", [f"t::{i}: inconclusive" for i in range(inconclusive)])
    monkeypatch.setattr(steal, "_verdict", [])
    session = SimpleNamespace(exitstatus=0, config=SimpleNamespace(option=SimpleNamespace(collectonly=False)))
    steal.pytest_sessionfinish(session, 0)  # type: ignore[arg-type]
    return int(session.exitstatus)


def test_a_run_says_how_many_tests_needed_another_attempt_and_fails_past_the_limit(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    evidence = tmp_path / "evidence.json"
    assert _finish(monkeypatch, evidence, steal.MAX_REATTEMPTED, 0) == 0
    assert steal._verdict == [f"timing evidence: {steal.MAX_REATTEMPTED} test(s) needed another attempt "
                              f"(at most {steal.MAX_REATTEMPTED}), 0 inconclusive (the run before: 0)"]
    assert _finish(monkeypatch, evidence, steal.MAX_REATTEMPTED + 1, 0) == 1
    assert steal._verdict[-1].startswith(f"FAILED: more than {steal.MAX_REATTEMPTED} tests needed another")


def test_a_test_inconclusive_in_two_runs_in_a_row_fails_the_second(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    evidence = tmp_path / "evidence.json"
    assert _finish(monkeypatch, evidence, 0, 1) == 0      # once: reported, kept in the file
    assert json.loads(evidence.read_text()) == {"inconclusive": 1, "reattempted": 0}
    assert _finish(monkeypatch, evidence, 0, 1) == 1      # again in the next run: a failure
    assert _finish(monkeypatch, evidence, 0, 0) == 0
    assert _finish(monkeypatch, evidence, 0, 1) == 0      # after a conclusive run: once again
