"""tests/steal.py reads the platform's evidence from the DPUs' own logs: the lines it parses are
made here from the format strings in dpu/, so a reworded log line fails here, not silently there."""

from __future__ import annotations

import re
from pathlib import Path

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
