"""The report as rich tables: per DPU (the paper's Table 1), per process, faults.

Rendering is deterministic (no clock, no terminal-dependent content beyond the
console's width), so `skel run` and `skel report` print the same tables for one run.
"""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

from .report import RunReport


def _num(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def _paper(paper: dict[Any, Any] | None, dpu: int) -> dict[str, Any] | None:
    if not paper:
        return None
    return paper.get(dpu) or paper.get(str(dpu))


def dpu_table(report: RunReport, paper: dict[Any, Any] | None = None) -> Table:
    table = Table(title=f"{report.system}: run {report.run_id}, generation {report.generation} — per DPU")
    table.add_column("DPU", justify="right")
    table.add_column("cycle ms\nconfigured", justify="right")
    table.add_column("cycle ms\nmeasured", justify="right")
    table.add_column("processes")
    for name in ("% compute", "% communicate", "% wait"):
        table.add_column(name, justify="right")
    table.add_column("% overhead", justify="right")
    table.add_column("static\nload %", justify="right")
    table.add_column("overruns", justify="right")
    for d in report.dpus:
        ref = _paper(paper, d.id)

        def pair(ours: float | None, key: str, digits: int = 1, ref: dict[str, Any] | None = ref) -> str:
            text = _num(ours, digits)
            if ref is not None and ref.get(key) is not None:
                text += f" ({ref[key]:.{digits}f})"
            return text

        table.add_row(
            str(d.id),
            _num(d.configured_cycle_ms, 2),
            pair(d.measured_cycle_ms, "cycle_ms", 2),
            ", ".join(d.processes),
            pair(d.compute_pct, "compute_pct"),
            pair(d.communicate_pct, "communicate_pct"),
            pair(d.wait_pct, "wait_pct"),
            _num(d.overhead_pct),
            _num(d.static_load_pct),
            str(d.overruns),
        )
    if paper:
        table.caption = "(in brackets: the paper's Table 1)"
    return table


def process_table(report: RunReport) -> Table:
    table = Table(title=f"per process (warm-up: first {report.warmup_cycles} cycles excluded)")
    table.add_column("process")
    table.add_column("DPU", justify="right")
    table.add_column("cycles", justify="right")
    table.add_column("overruns", justify="right")
    table.add_column("latency µs\np50 / p99 / max", justify="right")
    table.add_column("compute\nmean µs", justify="right")
    table.add_column("late /\ntoo late", justify="right")
    table.add_column("inputs: new / stale / dropped")
    for p in report.processes:
        lat = p.latency_us
        inputs = "\n".join(f"{i.buffer}: {i.new} / {i.stale} / {i.dropped}" for i in p.inputs) or "-"
        table.add_row(
            p.name,
            str(p.dpu),
            str(p.cycles),
            str(p.overruns),
            f"{_num(lat.p50)} / {_num(lat.p99)} / {_num(lat.max)}",
            _num(p.compute_mean_us),
            f"{p.late} / {p.too_late}",
            inputs,
        )
    return table


def fault_table(report: RunReport) -> Table:
    table = Table(title="faults")
    for name in ("kind", "process", "DPU", "buffer", "writer", "cycle", "chain / detail"):
        table.add_column(name)
    for f in report.faults:
        chain = " -> ".join(f.chain)
        table.add_row(
            f.kind,
            f.process or "-",
            "-" if f.dpu is None else str(f.dpu),
            f.buffer or "-",
            f.writer or "-",
            "-" if f.cycle is None else str(f.cycle),
            f"{chain}\n{f.detail}" if chain else f.detail,
        )
    return table


def damage_lines(report: RunReport) -> list[str]:
    """What the reader could not use, in one line each (none for a clean log)."""
    integ = report.integrity
    lines = []
    if integ.damaged:
        lost = sum(b["to_seq"] - b["from_seq"] + 1 for b in integ.lost_batches)
        lines.append(
            f"log damaged: {len(integ.corrupt_ranges)} corrupt ranges ({integ.corrupt_bytes} bytes), "
            f"{lost} timing batches lost; the tables use everything else"
        )
    if integ.malformed:
        per_channel = ", ".join(f"{c}: {n}" for c, n in integ.malformed.items())
        lines.append(f"malformed messages skipped: {per_channel}")
    return lines


def print_report(
    report: RunReport, console: Console | None = None, paper: dict[Any, Any] | None = None
) -> None:
    console = console or Console()
    console.print(dpu_table(report, paper))
    console.print(process_table(report))
    if report.faults:
        console.print(fault_table(report))
    for line in damage_lines(report):
        console.print(line, style="yellow", markup=False, highlight=False)
