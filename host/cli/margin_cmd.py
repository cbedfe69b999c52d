"""`skel margin FILE`: how far each DPU and process is from a fatal flaw, along one axis
(host/theory/margin.py): predicted from the file alone, and with --simulate on the executives
themselves, on virtual time (host/live/simulate.py)."""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from skeleton.analysis.errors import EXIT_BAD_INPUT, EXIT_OK
from skeleton.analysis.views.console import OutputConsole, output_console
from skeleton.analysis.views.tables import make_table

from ..model import System
from ..theory.margin import AXES, MOST, Margin, Scope, margin, scopes

if TYPE_CHECKING:
    from ..live.sweep import Sweep  # the sweep loads the live layer: only for --measure

SIMULATED_PRECISION = 1e-4


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:  # type: ignore[type-arg]
    p = sub.add_parser("margin", help="how far from failure: the largest factor each DPU and process "
                       "can grow by before a fatal flaw, predicted and simulated")
    p.add_argument("--axis", choices=AXES, default="compute",
                   help="compute: computations times the factor (default); rate: every period divided "
                        "by it; bytes: every buffer's size times it")
    p.add_argument("--process", action="append", default=[], metavar="P",
                   help="the margin of process P's computation (repeatable; compute axis)")
    p.add_argument("--dpu", action="append", default=[], type=int, metavar="D",
                   help="the margin of DPU D's computations together (repeatable; compute axis)")
    p.add_argument("--simulate", action="store_true",
                   help="also search on the executives themselves, on virtual time (a second a scope)")
    p.add_argument("--measure", action="store_true",
                   help="also measure it on the real DPUs, in one run of live pushes, restarting nothing "
                        "(compute axis; all processes, or the one --dpu or --process given)")
    p.add_argument("--hold", type=int, default=2, metavar="N",
                   help="with --measure: hold each step N hyperperiods of the DPUs' shared grid (default 2, "
                        "at least 1 s)")
    p.add_argument("--spawn", action="store_true",
                   help="with --measure: start local DPUs and stop them after")
    p.add_argument("--out", type=Path, help="with --measure: the sweep's run directory (default "
                   "runs/<system>-margin-<time>/)")
    p.add_argument("--plots", type=Path, metavar="DIR",
                   help="write DIR/margin-AXIS.png: each DPU's load and each process's worst response "
                        "against the factor, the margin marked (and a measured sweep's steps)")
    p.add_argument("--json", action="store_true", help="the margins as JSON")
    return p


def _factor(m: Margin | None) -> str:
    if m is None:
        return "-"
    return f"> {MOST:g}" if m.factor is None else f"{m.factor:.4f}"


def _measured_scopes(system: System, args: argparse.Namespace) -> list[Scope]:
    """What --measure sweeps: the scopes asked for, or all processes together and each DPU."""
    if args.process or args.dpu:
        return scopes(system, args.process, args.dpu)
    return [Scope()] + [Scope(dpu=d.id) for d in system.dpus]


def margin_command(args: argparse.Namespace, system: System) -> int:
    from ..live.simulate import simulated_flaws

    names = {p.name for p in system.processes}
    unknown = [p for p in args.process if p not in names] + [str(d) for d in args.dpu
                                                             if d not in {x.id for x in system.dpus}]
    if unknown:
        print(f"skel margin: no such process or DPU in {system.path}: {', '.join(unknown)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.hold < 1:
        print(f"skel margin: --hold {args.hold}: at least 1 hyperperiod", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.axis != "compute" and (args.process or args.dpu or args.measure):
        print(f"skel margin: --axis {args.axis} grows the whole system: --process, --dpu and --measure are "
              "for the compute axis", file=sys.stderr)
        return EXIT_BAD_INPUT
    wanted = scopes(system, args.process, args.dpu) if args.axis == "compute" else [Scope()]
    rows = []
    for scope in wanted:
        predicted = margin(system, args.axis, scope)
        simulated = (margin(system, args.axis, scope, probe=simulated_flaws, precision=SIMULATED_PRECISION)
                     if args.simulate else None)
        rows.append((scope, predicted, simulated))
    swept: dict[str, Sweep] = {}
    if args.measure:
        from ..live.sweep import measure

        out = args.out or Path("runs") / f"{system.name}-margin-{time.strftime('%Y%m%d-%H%M%S')}"
        # its progress on stderr with --json: stdout stays pure JSON
        said = OutputConsole(stderr=True) if args.json else output_console()
        predicted_of = {s.name: p.factor for s, p, _ in rows}
        for scope in _measured_scopes(system, args):
            if predicted_of[scope.name] is None:
                said.print(f"{scope.name}: nothing limits it up to the search's limit: not measured")
                continue
            said.print(f"measuring {scope.name}")
            swept[scope.name] = measure(system, scope, predicted_of[scope.name], out / _slug(scope), said,
                                        spawn_dpus=args.spawn, key=args.key, hyperperiods=args.hold)
    if args.plots is not None:
        from .margin_plot import write_margin_plot  # matplotlib: only for --plots

        first = swept.get(rows[0][0].name)
        steps = [(s.factor, s.compute_pct) for s in first.steps] if first else []
        made = write_margin_plot(system, rows[0][1], args.plots, steps)
        print(f"plot: {made}", file=sys.stderr)
    if args.json:
        print(json.dumps({"system": system.name, "axis": args.axis, "margins": [
            {"scope": s.name, "predicted": p.to_json(), "simulated": m.to_json() if m else None,
             "measured": _sweep_json(swept.get(s.name))} for s, p, m in rows]}, indent=2))
        return EXIT_OK
    _print(system.name, args.axis, rows, swept)
    for scope_name, one in swept.items():
        _print_sweep(scope_name, one)
    return EXIT_OK


def _slug(scope: Scope) -> str:
    if scope.process is not None:
        return f"process-{scope.process}"
    return f"dpu-{scope.dpu}" if scope.dpu is not None else "all"


def _sweep_json(swept: Sweep | None) -> dict[str, object] | None:
    if swept is None:
        return None
    return {"factor": swept.margin, "run": str(swept.out),
            "steps": [{"factor": s.factor, "generation": s.generation, "heard": s.heard, "flaw": s.flaw,
                       "compute_pct": s.compute_pct, "platform": s.platform} for s in swept.steps]}


def _measured(swept: Sweep) -> str:
    """The measured margin: `<` the first step when it was flawed already, `>=` when the sweep
    ended on heartbeats the log puts down to the platform."""
    last = swept.steps[-1]
    if swept.margin is None:
        return f"< {swept.steps[0].factor:.4f}"
    return f">= {swept.margin:.4f}" if last.heard and last.flaw is None else f"{swept.margin:.4f}"


def _print_sweep(scope: str, swept: Sweep) -> None:
    """A sweep in a few lines: its steps, what flawed the first flawed one and what the platform
    cost there; its log holds the rest."""
    console = output_console()

    def say(line: str) -> None:
        console.print(line, markup=False, highlight=False, soft_wrap=True)

    steps = ", ".join(f"x{s.factor:.4f} {'clean' if s.flaw is None else 'FLAWED'}" for s in swept.steps)
    say(f"{scope}: measured {_measured(swept)} in one run of live pushes: {steps}")
    for step in swept.steps:
        if step.flaw is not None:
            say(f"  x{step.factor:.4f}: {step.flaw}")
        if step.platform:
            say(f"  x{step.factor:.4f} beside its simulation, the platform's cost: {step.platform}")
    last = swept.steps[-1]
    if last.heard and last.flaw is None:
        say(f"  the heartbeats ended the sweep at x{last.factor:.4f} ({last.heard}); its window in the log "
            "puts them down to the platform's stalls")
    say(f"  every step's window: skel report {swept.out} --all")


def _print(name: str, axis: str, rows: list[tuple[Scope, Margin, Margin | None]],
           swept: dict[str, Sweep]) -> None:
    """The margins; each sweep's measured one beside its scope."""
    grows = {"compute": "computations times", "rate": "every period divided by",
             "bytes": "buffer sizes times"}
    console = output_console()
    simulated = any(m is not None for _, _, m in rows)
    columns = [("scope", False), ("predicted", True)] + ([("simulated", True)] if simulated else [])
    if swept:
        columns.append(("measured", True))
    columns.append(("breaks first (predicted)", False))
    table_rows = []
    for s, p, m in rows:
        row = [s.name, _factor(p), *([_factor(m)] if simulated else [])]
        if swept:
            one = swept.get(s.name)
            row.append("-" if one is None else _measured(one))
        table_rows.append([*row, p.breaks[0] if p.breaks else "nothing up to the limit"])
    table = make_table(f"{name}: the largest factor before a fatal flaw ({grows[axis]} it)", columns,
                       table_rows)
    console.print(table)
    for line in rows[0][1].paced:
        console.print(f"note: {line}", markup=False, highlight=False)
