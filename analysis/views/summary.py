"""One screen of a run: the verdict, the per-DPU table (the paper's Table 1 beside it when
asked), the faults and the prediction's deltas counted by kind, and where the rest is.

What `skel run` and `skel report` print unless `--all` asks for every table
(tables.print_report). It fits SCREEN_LINES lines of SCREEN_COLUMNS columns for a system
the size of SERVO; a larger one keeps its DPU_ROWS busiest DPUs and says how many more.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

from rich.console import Console

from ..measure.faults import Fault
from ..measure.predicted import Beside, Predicted
from ..measure.report import RunReport
from ..measure.simulated import NAMED_POINTS, Simulation
from .console import OutputConsole
from .tables import damage_lines, faithful_lines, make_table, num, paper_table, signed, stopped_lines

SCREEN_LINES = 60
SCREEN_COLUMNS = 120
DPU_ROWS = 24
FAULT_LINES = 4  # fatal faults named one by one; the rest are counted

FAILED_KINDS = ("dpu_lost", "delivery")  # the machine or network failed the run, not the design


def fault_line(fault: Fault) -> str:
    """One fault in one line, as `skel run` prints it live and `skel watch` lists it."""
    where = f"{fault.process} (DPU {fault.dpu})" if fault.process else f"DPU {fault.dpu}"
    if fault.kind == "lockout":
        waits = fault.detail
        if fault.buffer and fault.writer:
            waits = f"waiting on {fault.buffer} from {fault.writer}"
        if fault.buffer and fault.writer and fault.at_s is not None:
            waits += f"; not completed by {fault.at_s:.3f} s"
        return f"lockout: {where} at cycle {fault.cycle}, {waits}"
    if fault.kind == "jam":
        return f"jam: {' -> '.join(fault.chain)}: {fault.detail}"
    if fault.kind == "dpu_lost":
        return f"dpu_lost: DPU {fault.dpu} {fault.detail}"
    if fault.kind in ("stall", "behind"):
        return f"{fault.kind}: {fault.detail}"   # the detail names the host or DPU
    if fault.kind == "overrun":
        return f"overrun: {where} from cycle {fault.cycle}"
    return f"{fault.kind}: {where}: {fault.detail}"


def screen_console(console: Console | None = None) -> Console:
    """The console a summary prints on: SCREEN_COLUMNS wide, or a terminal's own width when
    narrower; the same file and colours as `console`."""
    if console is not None and console.is_terminal and console.width <= SCREEN_COLUMNS:
        return console
    if console is None:
        return OutputConsole(width=SCREEN_COLUMNS)
    return OutputConsole(width=SCREEN_COLUMNS, file=console.file, force_terminal=console.is_terminal,
                         no_color=console.no_color)


def verdict(report: RunReport) -> str:
    """The run in one line: what it is, and whether the architecture works."""
    simulated = " (simulated)" if report.simulated else ""
    head = f"{report.system}, run {report.run_id}{simulated}, generation {report.generation}"
    fatal = [f for f in report.faults if f.fatal]
    failed = [f for f in report.faults if f.kind in FAILED_KINDS]
    if fatal:
        return f"{head}: FATAL FLAW: {len(fatal)} fatal fault{_s(len(fatal))} (a lockout, a jam), below"
    if failed:
        return f"{head}: FAILED: {len(failed)} DPU lost or buffer not delivered, below"
    p = report.predicted
    if p is not None and p.outside:
        return f"{head}: no fatal flaw; {len(p.outside)} figure{_s(len(p.outside))} outside the prediction"
    if p is not None:
        return f"{head}: no fatal flaw; every figure within its prediction"
    return f"{head}: no fatal flaw (no lockout, no jam)"


def dpu_summary_table(report: RunReport) -> Any:
    """Per DPU (the paper's Table 1), with the predicted and the simulated % compute beside the
    measured."""
    predicted = {d.id: d.compute_pct for d in report.predicted.dpus} if report.predicted else {}
    simulated = {d.id: d for d in report.simulation.dpus} if report.simulation else {}
    dpus = report.dpus
    if len(dpus) > DPU_ROWS:
        busiest = {d.id for d in sorted(dpus, key=lambda d: -(d.compute_pct or 0.0))[:DPU_ROWS]}
        dpus = [d for d in dpus if d.id in busiest]
    rows = []
    for d in dpus:
        pred, sim = predicted.get(d.id), simulated.get(d.id)
        row = [str(d.id), num(d.measured_cycle_ms, 2), ", ".join(d.processes), num(d.compute_pct),
               num(pred.predicted) if pred else "-"]
        if simulated:
            row.append(num(sim.simulated_compute_pct) if sim else "-")
        rows.append([*row, num(d.communicate_pct), num(d.wait_pct), num(d.overhead_pct),
                     num(d.release_latency_us.p99, 0), num(d.stall_ms)])
    columns = [("DPU", True), ("cycle\nms", True), ("processes", False), ("% comp", True), ("pred.", True)]
    if simulated:
        columns.append(("sim.", True))
    columns += [("% comm", True), ("% wait", True), ("% ovhd", True), ("wake\np99 µs", True),
                ("stall\nms", True)]
    title = "per DPU"
    if len(dpus) < len(report.dpus):
        title += f": the {len(dpus)} busiest of {len(report.dpus)}"
    return make_table(title, columns, rows)


def fault_lines(faults: Sequence[Fault]) -> list[str]:
    """The faults: fatal and failing ones named (FAULT_LINES at most, first), the platform's counted."""
    # A jam names the chain back to its root cause: it leads, before the lockouts it explains.
    named = sorted((f for f in faults if f.fatal or f.kind in FAILED_KINDS), key=lambda f: f.kind != "jam")
    lines = [fault_line(f) for f in named[:FAULT_LINES]]
    if len(named) > FAULT_LINES:
        lines.append(f"... and {len(named) - FAULT_LINES} more such faults")
    stalls = [f for f in faults if f.kind == "stall"]
    if stalls:
        # A stall fault is one stop of a host's DPUs, or a count of the short ones.
        times = sum(f.count or 1 for f in stalls)
        longest = max((f.duration_ms or 0.0) for f in stalls)
        lines.append(f"stall: the platform stopped DPUs {times} time{_s(times)}, the longest for "
                     f"{longest:.1f} ms (not the design)")
    behind = [f for f in faults if f.kind == "behind" and not f.fatal]
    if behind:
        worst = max((f.behind_ms or 0.0) for f in behind)
        dpus = ", ".join(str(d) for d in sorted({f.dpu for f in behind if f.dpu is not None}))
        lines.append(f"behind: DPU {dpus} behind its schedule {len(behind)} time{_s(len(behind))}, "
                     f"up to {worst:.1f} ms, kept from running by the platform")
    overruns = [f for f in faults if f.kind == "overrun"]
    if overruns:
        cycles = sum(f.count or 0 for f in overruns)
        lines.append(f"overrun: {cycles} cycle{_s(cycles)} of {len(overruns)} process{_es(len(overruns))} "
                     "ended after their next release")
    return lines


def platform_summary(simulation: Simulation) -> list[str]:
    """Measured beside simulated: each DPU whose measurement the platform moved, and by what."""
    lines = []
    for d in simulation.dpus:
        if d.named is None:
            continue
        others = ", ".join(f"{kind} {signed(points, 1)}" for kind, points in d.costs.items()
                           if kind != d.named)
        lines.append(f"DPU {d.id}: {d.named} {signed(d.cost_points, 1)} points"
                     + (f" ({others})" if others else ""))
    return lines


def predicted_summary(p: Predicted) -> list[str]:
    """The figures outside their prediction, one line per kind with the range of deltas."""
    groups: list[tuple[str, list[Beside], int, str]] = [
        ("% compute", [d.compute_pct for d in p.dpus], 1, f" points (beyond ±{p.compute_points:g})"),
        ("response p99", [r.response_us for r in p.processes], 0,
         f" µs above the worst (late_pct: {p.late_pct} % of the period)"),
        ("new share", [i.new for i in p.inputs], 2, f" (beyond ±{p.share:g})"),
        ("dropped per cycle", [i.dropped for i in p.inputs], 2, f" (beyond ±{p.share:g})"),
        ("chain latency p99", [c.latency_us for c in p.chains], 0,
         f" µs above the worst (late_pct: {p.late_pct} % of the tail's period)"),
    ]
    lines = []
    for what, figures, digits, tolerance in groups:
        outside = [b.delta for b in figures if b.outside and b.delta is not None]
        if outside:
            low, high = signed(min(outside), digits), signed(max(outside), digits)
            span = low if low == high else f"{low} to {high}"
            lines.append(f"{what}: {len(outside)} of {len(figures)}, {span}{tolerance}")
    return lines


def print_summary(report: RunReport, console: Console | None = None, paper: dict[Any, Any] | None = None,
                  where: str | None = None) -> None:
    """One screen of `report`; `where` names the run directory (or log) for the pointer to the rest."""
    console = screen_console(console)

    def say(line: str, style: str | None = None) -> None:
        console.print(line, style=style, markup=False, highlight=False)

    say(verdict(report), "bold")
    if len(report.windows) > 1:
        say(f"{len(report.windows)} generation windows: the tables are the last one's "
            f"(generation {report.generation})")
    console.print(dpu_summary_table(report))
    if paper:
        console.print(paper_table(report, paper))
    serious = min(FAULT_LINES + 1, sum(1 for f in report.faults if f.fatal or f.kind in FAILED_KINDS))
    for i, line in enumerate(fault_lines(report.faults)):
        say(line, "red" if i < serious else "yellow")
    if report.simulation is not None:
        moved = platform_summary(report.simulation)
        say(f"beside its simulation ({report.simulation.where}): " +
            ("the platform's cost, by DPU:" if moved else "every DPU ran as simulated, within "
             f"{NAMED_POINTS:g} point"), "yellow" if moved else None)
        for line in moved:
            say(f"  {line}", "yellow")
    if report.predicted is not None and report.predicted.outside:
        say(f"outside the prediction, put down to {report.predicted.cause}:", "yellow")
        for line in predicted_summary(report.predicted):
            say(f"  {line}", "yellow")
    for line in stopped_lines(report) + faithful_lines(report) + damage_lines(report):
        say(line, "yellow")
    if where is not None:   # a path is not broken across lines, however long
        console.print(rest_line(where), markup=False, highlight=False, soft_wrap=True)


def rest_line(where: str) -> str:
    """Where the rest of a run is, after its one screen."""
    return f"the rest: skel report {where} --all (every table), --json, --plots DIR"


def _s(n: int) -> str:
    return "" if n == 1 else "s"


def _es(n: int) -> str:
    return "" if n == 1 else "es"
