"""analysis/views/summary.py: one screen of a run, on a synthetic log."""

from __future__ import annotations

import dataclasses
import io
from pathlib import Path

from analysis_synth import batches, report, small_config, small_run, status, write_log
from rich.console import Console

from skeleton.analysis.measure.faults import Fault
from skeleton.analysis.measure.predicted import Beside, DpuBeside, Predicted, ProcessBeside
from skeleton.analysis.measure.report import RunReport
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.summary import (
    DPU_ROWS,
    SCREEN_COLUMNS,
    fault_lines,
    predicted_summary,
    print_summary,
    verdict,
)
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL


def _report(tmp_path: Path) -> RunReport:
    dpu1, dpu2 = small_run()
    t1, t2 = batches(1, dpu1, 4), batches(2, dpu2, 2)
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config())]
    events += [(TIMING_CHANNEL, t) for t in t1 + t2]
    events += [(STATUS_CHANNEL, status(1, [])), (STATUS_CHANNEL, status(2, []))]
    events += [(REPORT_CHANNEL, report(1, len(t1))), (REPORT_CHANNEL, report(2, len(t2)))]
    return load_run(str(write_log(tmp_path / "run.lcm", events)), None).report


def _printed(rep: RunReport, width: int = 200, paper: dict | None = None) -> list[str]:
    out = io.StringIO()
    print_summary(rep, console=Console(file=out, width=width), paper=paper, where="RUN")
    return out.getvalue().splitlines()


def test_a_clean_run_is_one_short_screen_led_by_its_verdict(tmp_path: Path) -> None:
    rep = _report(tmp_path)
    lines = _printed(rep)
    assert lines[0] == f"{rep.system}, run {rep.run_id}, generation {rep.generation}: no fatal flaw " \
                       "(no lockout, no jam)"
    assert any("per DPU" in line for line in lines)
    assert lines[-1] == "the rest: skel report RUN --all (every table), --json, --plots DIR"
    assert len(lines) <= 60 and max(map(len, lines)) <= SCREEN_COLUMNS


def test_the_paper_table_is_beside_ours_when_asked(tmp_path: Path) -> None:
    rep = _report(tmp_path)
    paper = {d.id: {"cycle_ms": 5.0, "compute_pct": 50.0, "communicate_pct": 9.0, "wait_pct": 1.0}
             for d in rep.dpus}
    lines = _printed(rep, paper=paper)
    assert any("the paper's Table 1 beside this run" in line for line in lines)


def test_a_fatal_fault_leads_the_verdict_and_is_named(tmp_path: Path) -> None:
    rep = _report(tmp_path)
    lockout = Fault(kind="lockout", process="p1", dpu=1, buffer="b", writer="p2", cycle=7, at_s=0.5)
    rep = dataclasses.replace(rep, faults=[lockout])
    assert verdict(rep).endswith("FATAL FLAW: 1 fatal fault (a lockout, a jam), below")
    assert "lockout: p1 (DPU 1) at cycle 7, waiting on b from p2; not completed by 0.500 s" in _printed(rep)


def test_a_jam_leads_the_lockouts_it_explains() -> None:
    lockouts = [Fault(kind="lockout", process=f"p{i}", dpu=1, cycle=i, detail="x") for i in range(6)]
    jam = Fault(kind="jam", chain=["p5", "p0"], detail="DPU 1 overloaded")
    lines = fault_lines([*lockouts, jam])
    assert lines[0] == "jam: p5 -> p0: DPU 1 overloaded"
    assert lines[1:] == ["lockout: p0 (DPU 1) at cycle 0, x", "lockout: p1 (DPU 1) at cycle 1, x",
                         "lockout: p2 (DPU 1) at cycle 2, x", "... and 3 more such faults"]


def test_the_paper_table_takes_a_dpu_with_no_measured_cycle(tmp_path: Path) -> None:
    """DPU 4's warm-up can outlast a short run: no % compute measured, no delta, no crash."""
    rep = _report(tmp_path)
    rep = dataclasses.replace(rep, dpus=[dataclasses.replace(rep.dpus[0], compute_pct=None), *rep.dpus[1:]])
    paper = {d.id: {"cycle_ms": 5.0, "compute_pct": 50.0, "communicate_pct": 9.0, "wait_pct": 1.0}
             for d in rep.dpus}
    assert any("the paper's Table 1 beside this run" in line for line in _printed(rep, paper=paper))


def test_the_platforms_faults_are_counted_not_listed() -> None:
    stalls = [Fault(kind="stall", dpus=[1], duration_ms=ms) for ms in (6.0, 9.5)]
    stalls.append(Fault(kind="stall", dpus=[1, 2], duration_ms=4.0, count=12))  # the short ones
    overruns = [Fault(kind="overrun", process=p, dpu=1, count=n) for p, n in (("a", 3), ("b", 4))]
    lines = fault_lines([*stalls, *overruns])
    assert lines == ["stall: the platform stopped DPUs 14 times, the longest for 9.5 ms (not the design)",
                     "overrun: 7 cycles of 2 processes ended after their next release"]


def test_figures_outside_the_prediction_are_one_line_per_kind_with_their_range() -> None:
    p = Predicted(generation=1, compute_points=2.0, share=0.05, late_pct=20)
    p.dpus = [DpuBeside(1, Beside(90.0, 90.5, 0.5, False)), DpuBeside(2, Beside(70.0, 60.0, -10.0, True))]
    p.processes = [ProcessBeside(f"p{i}", 1, Beside(1000.0, 1000.0 + d, d, True), None, None)
                   for i, d in enumerate((3000.0, 500.0, 9000.0))]
    p.outside = ["one line per figure"] * 4
    assert predicted_summary(p) == [
        "% compute: 1 of 2, -10.0 points (beyond ±2)",
        "response p99: 3 of 3, +500 to +9000 µs above the worst (late_pct: 20 % of the period)"]


def test_a_large_system_shows_its_busiest_dpus_and_says_how_many_more(tmp_path: Path) -> None:
    rep = _report(tmp_path)
    base = rep.dpus[0]
    many = [dataclasses.replace(base, id=i, compute_pct=float(i)) for i in range(1, 65)]
    lines = _printed(dataclasses.replace(rep, dpus=many))
    assert any(f"per DPU: the {DPU_ROWS} busiest of 64" in line for line in lines)
    shown = {int(line.split()[1]) for line in lines if line.startswith("│") and line.split()[1].isdigit()}
    assert shown == set(range(64 - DPU_ROWS + 1, 65))
    assert len(lines) <= 60
