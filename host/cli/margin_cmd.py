"""`skel margin FILE`: how far each DPU and process is from a fatal flaw, along one axis
(host/theory/margin.py): predicted from the file alone, and with --simulate on the executives
themselves, on virtual time (host/live/simulate.py)."""

from __future__ import annotations

import argparse
import json
import sys

from skeleton.analysis.errors import EXIT_BAD_INPUT, EXIT_OK

from ..model import System
from ..theory.margin import AXES, MOST, Margin, Scope, margin, scopes

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
    p.add_argument("--json", action="store_true", help="the margins as JSON")
    return p


def _factor(m: Margin | None) -> str:
    if m is None:
        return "-"
    return f"> {MOST:g}" if m.factor is None else f"{m.factor:.4f}"


def margin_command(args: argparse.Namespace, system: System) -> int:
    from ..live.simulate import simulated_flaws

    names = {p.name for p in system.processes}
    unknown = [p for p in args.process if p not in names] + [str(d) for d in args.dpu
                                                             if d not in {x.id for x in system.dpus}]
    if unknown:
        print(f"skel margin: no such process or DPU in {system.path}: {', '.join(unknown)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.axis != "compute" and (args.process or args.dpu):
        print(f"skel margin: --axis {args.axis} grows the whole system: --process and --dpu are for "
              "the compute axis", file=sys.stderr)
        return EXIT_BAD_INPUT
    wanted = scopes(system, args.process, args.dpu) if args.axis == "compute" else [Scope()]
    rows = []
    for scope in wanted:
        predicted = margin(system, args.axis, scope)
        simulated = (margin(system, args.axis, scope, probe=simulated_flaws, precision=SIMULATED_PRECISION)
                     if args.simulate else None)
        rows.append((scope, predicted, simulated))
    if args.json:
        print(json.dumps({"system": system.name, "axis": args.axis, "margins": [
            {"scope": s.name, "predicted": p.to_json(), "simulated": m.to_json() if m else None}
            for s, p, m in rows]}, indent=2))
        return EXIT_OK
    _print(system.name, args.axis, rows)
    return EXIT_OK


def _print(name: str, axis: str, rows: list[tuple[Scope, Margin, Margin | None]]) -> None:
    from skeleton.analysis.views.console import output_console
    from skeleton.analysis.views.tables import make_table

    grows = {"compute": "computations times", "rate": "every period divided by",
             "bytes": "buffer sizes times"}
    console = output_console()
    simulated = any(m is not None for _, _, m in rows)
    columns = [("scope", False), ("predicted", True)] + ([("simulated", True)] if simulated else [])
    columns.append(("breaks first (predicted)", False))
    table = make_table(f"{name}: the largest factor before a fatal flaw ({grows[axis]} it)", columns,
                       [[s.name, _factor(p), *([_factor(m)] if simulated else []),
                         p.breaks[0] if p.breaks else "nothing up to the limit"] for s, p, m in rows])
    console.print(table)
    for line in rows[0][1].paced:
        console.print(f"note: {line}", markup=False, highlight=False)
