"""How a run is asked for and how it ends: the options of `skel run` and `skel simulate`, the
instants both share, and the one screen (or every table, or report.json) both print from the
recorded log, through the same analysis as `skel report`."""

from __future__ import annotations

import dataclasses
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console

from skeleton.analysis.errors import EXIT_FAILED, EXIT_FATAL_FLAW, EXIT_OK
from skeleton.analysis.measure.run import RunAnalysis, load_run
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.views.summary import FAILED_KINDS, print_summary, rest_line
from skeleton.analysis.views.tables import print_report

from ..model import System
from ..theory.predictor import predictor
from .repair import RepairResult

START_LEAD_S = 0.5          # time for START to reach every DPU before cycle 0
HEAR_TIMEOUT_S = 5.0
FAULT_WINDOW_MAX_S = 1.0    # a run stopped early (run.stop_on) goes on at most this long


@dataclass
class RunOptions:
    spawn: bool = False
    cycles: int | None = None
    duration_s: float | None = None
    out: Path | None = None
    as_json: bool = False
    compare_paper: bool = False
    all_tables: bool = False  # every table, not one screen
    # Run the generation `skel push` already applied, when every DPU still has it.
    pushed_generation: int | None = None
    dpu_args: list[str] = field(default_factory=list)
    wait_dpus_s: float = HEAR_TIMEOUT_S
    logger: str = "local"   # local: lcm-logger here; external: someone else records the run
    force: bool = False     # take over another host tool's run on our DPUs (host/live/owner.py)
    key: bytes | None = None        # signed control (analysis/read/seal.py): the key ...
    key_file: Path | None = None    # ... and its file, which spawned DPUs are given


def control_url(system: System) -> str:
    return system.default_link.url


def fault_window_s(system: System) -> float:
    """How long a run stopped early goes on: one lockout window of its slowest process (at
    most FAULT_WINDOW_MAX_S), so the lockouts that come with the first (the rest of a jam:
    processes downstream, or on a DPU that falls behind a little later) are recorded too."""
    slowest_us = max(p.period_us for p in system.processes)
    return min(FAULT_WINDOW_MAX_S, system.run.lockout_cycles * slowest_us / 1e6)


def report_run(console: Console, system: System, options: RunOptions, out: Path, run_id: int,
               lost: set[int], repaired: RepairResult, restarts: int = 0, problems: Sequence[str] = (),
               simulated: RunAnalysis | None = None, analysis: RunAnalysis | None = None) -> int:
    """The tables, with what makes the run's log or the run itself incomplete said first;
    `simulated`: a simulated run of the same system, laid beside this one; `analysis`: the
    run's log analysed already (a simulation's)."""
    for problem in problems:
        console.print(f"[bold red]INCOMPLETE[/] {problem}", soft_wrap=True)
    try:
        run = analysis or load_run(out / "run.lcm", run_id=run_id, key=options.key)
    except LogError as error:
        console.print(f"[red]{out / 'run.lcm'}: {error}[/]")
        return EXIT_FAILED
    missing = run.add_prediction(predictor(system.path))
    if simulated is not None:
        run.add_simulation(simulated.report, str(Path(simulated.path).parent))
    report = run.report
    (out / "report.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
    if options.as_json:
        print(json.dumps(report.to_json(), indent=2))
        if missing:
            print(missing, file=sys.stderr)  # stdout stays pure JSON
    else:
        paper = None
        if options.compare_paper and system.reference is not None:
            paper = {i: dataclasses.asdict(row) for i, row in system.reference.dpus.items()}
        if options.all_tables:
            print_report(report, console=console, paper=paper)
        else:
            print_summary(report, console=console, paper=paper)
        if missing:
            console.print(missing, style="yellow", markup=False, highlight=False)
        if restarts:
            console.print(f"the logger died and was restarted {restarts} time{'s' if restarts > 1 else ''}")
        if repaired.asked:
            console.print(f"the logger missed {repaired.asked} messages; the DPUs sent them again"
                          + (f", {repaired.missing} still missing" if repaired.missing else ": all logged"))
        console.print(f"run written to {out}/ (system.yaml, run.lcm, report.json)")
        if not options.all_tables:
            console.print(rest_line(str(out)), highlight=False, soft_wrap=True)
    kinds = {f["kind"] for f in report.to_json()["faults"]}
    if "delivery" in kinds:
        return EXIT_FAILED  # what did not arrive locks its readers out: not the design's flaw
    if report.fatal:
        return EXIT_FATAL_FLAW
    # A lost DPU's part of the run is missing: the tables cover the others only.
    return EXIT_FAILED if lost or problems or kinds & set(FAILED_KINDS) else EXIT_OK
