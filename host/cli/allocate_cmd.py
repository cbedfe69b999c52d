"""`skel allocate FILE`: propose an allocation (allocate.py), write it as a new system file,
print its prediction beside the old one's, and with --verify run both and diff them."""

from __future__ import annotations

import argparse
import io
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from rich.console import Console

from skeleton.analysis.errors import EXIT_BAD_INPUT, EXIT_FAILED, EXIT_OK

from ..model import System
from ..sysfile.system import SystemFileError, load, with_url
from ..theory.predict import predict

if TYPE_CHECKING:
    from ..theory.allocate import Allocation

# allocate.py's goals; it is imported only to allocate (OR-Tools takes a while to load)
OBJECTIVES = ("load", "latency", "traffic")


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:  # type: ignore[type-arg]
    p = sub.add_parser("allocate", help="find an allocation of processes to DPUs (OR-Tools CP-SAT)")
    p.add_argument("--dpus", type=int, metavar="N", help="allocate to N DPUs (more than the file's: "
                   "copies of its last DPU are added)")
    p.add_argument("--objective", choices=OBJECTIVES, default="load",
                   help="minimise the worst DPU load (default), the worst chain latency, or the "
                        "traffic between DPUs")
    p.add_argument("--pin", action="append", default=[], metavar="PROCESS=DPU",
                   help="keep PROCESS on DPU (repeatable)")
    p.add_argument("--out", type=Path, metavar="NEW.yaml",
                   help="the new system file (default <system>-allocated.yaml here)")
    p.add_argument("--time-limit", type=float, default=10.0, metavar="S", help="solver time (default 10)")
    p.add_argument("--speed", type=float, metavar="X", help="every DPU at this speed (what if)")
    p.add_argument("--max-load", type=float, default=100.0, metavar="PCT",
                   help="every DPU's load and frames within PCT %% (headroom; default 100)")
    p.add_argument("--verify", action="store_true",
                   help="run both files (local DPUs in sleep mode) and print skel diff of the runs")
    return p


def _pins(system: System, given: list[str], dpus: list[int]) -> dict[str, int]:
    pins = {}
    for pin in given:
        name, _, dpu = pin.partition("=")
        if name not in {p.name for p in system.processes} or not dpu.isdigit() or int(dpu) not in dpus:
            raise SystemFileError(system.path, f"--pin {pin}", "give PROCESS=DPU: a process of the file "
                                  f"and one of the DPUs allocated to ({', '.join(map(str, dpus))})")
        pins[name] = int(dpu)
    return pins


def allocate_command(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.console import output_console

    from ..theory.allocate import NoFit, allocate, targets

    system = load(args.file, args.overrides)  # --url is the verifying runs', not the new file's
    old = predict(system)
    for error in old.errors:
        print(SystemFileError(system.path, error.path, error.problem), file=sys.stderr)
    if old.errors:
        return EXIT_BAD_INPUT
    bad = ("--dpus must be >= 1" if args.dpus is not None and args.dpus < 1
           else "--time-limit must be > 0" if not args.time_limit > 0
           else "--speed must be > 0" if args.speed is not None and not args.speed > 0
           else "--max-load must be in (0, 100]" if not 0 < args.max_load <= 100 else "")
    if bad:
        print(f"skel allocate: {bad}", file=sys.stderr)
        return EXIT_BAD_INPUT
    console = output_console()
    try:
        pins = _pins(system, args.pin, [d.id for d in targets(system, args.dpus, args.speed)])
        found = allocate(system, args.dpus, args.objective, pins, args.time_limit, args.speed,
                         args.max_load / 100)
    except NoFit as e:
        console.print(f"skel allocate: {e}", soft_wrap=True, markup=False)
        return EXIT_FAILED
    out = args.out or Path(f"{system.name}-allocated.yaml")
    out.write_text(found.text)
    _say(console, system, found, out)
    return _verify(console, system, out, args) if args.verify else EXIT_OK


def _say(console: Console, system: System, found: Allocation, out: Path) -> None:
    from ..theory.allocate import traffic_bytes_per_s
    from .predict_view import print_beside

    how = "proven optimal" if found.optimal else "the best found in the time limit"
    console.print(f"allocation ({found.objective}): {how}; {found.candidates} candidate(s) in "
                  f"{found.seconds:.2f} s; written to {out}", soft_wrap=True)
    print_beside(console, predict(system), found.prediction,
                 (traffic_bytes_per_s(system), traffic_bytes_per_s(found.system)))


def _verify(console: Console, system: System, new_path: Path, args: argparse.Namespace) -> int:
    """Both files, each on local DPUs in sleep mode, then `skel diff` of the two runs."""
    from skeleton.analysis.read.messages import run_log_path
    from skeleton.analysis.views.console import UNLIMITED_WIDTH
    from skeleton.analysis.views.diff import diff_command

    from ..live.run import RunOptions, run

    # beside the new file, so the runs are found with what they verify
    where = new_path.parent / f"{new_path.stem}-verify-{time.strftime('%Y%m%d-%H%M%S')}"
    codes = {}
    for tag, path, extra in (("before", args.file, args.overrides), ("after", new_path, [])):
        sleep = [f"dpu.{d.id}.compute=sleep" for d in load(path, extra).dpus]
        s = load(path, [*extra, *sleep])
        s = with_url(s, args.url) if args.url else s
        said = io.StringIO()
        codes[tag] = run(s, RunOptions(spawn=True, out=where / tag, key=args.key, key_file=args.key_file),
                         console=Console(file=said, width=UNLIMITED_WIDTH))
        if not run_log_path(where / tag).exists():
            # Refused before it started (DPUs of its ids already up, say): its own words say why.
            console.print(f"{tag}: {path} did not run, exit {codes[tag]}:", markup=False, highlight=False)
            console.print(said.getvalue().rstrip(), markup=False, highlight=False)
            return codes[tag] or EXIT_FAILED
        console.print(f"{tag}: {path} ran, exit {codes[tag]} ({where / tag})")
    diff_command(run_log_path(where / "before"), run_log_path(where / "after"), as_json=False, key=args.key)
    return codes["after"]
