"""`skel calibrate RUN`: the run's system file with each process that ran real code turned back
into a skeleton that computes what the code measured: its compute times in the run's measured
window, as a `samples:` file the DPUs draw from (host/sysfile/compute.py). The skeleton of the
whole system then evaluates the architecture with the real code's timing, on any allocation and
any machine, without the code."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError
from skeleton.analysis.measure.metrics import completed, measured
from skeleton.analysis.read.messages import open_run_log, run_log_path
from skeleton.analysis.read.records import load_records
from skeleton.analysis.views.console import output_console
from skeleton.analysis.views.tables import make_table

from ..model import System
from ..sysfile import yamledit
from ..sysfile.compute import table_of_samples
from ..sysfile.system import load, loads


class CalibrateError(SkelError):
    exit_code = EXIT_BAD_INPUT


def add_parser(sub: argparse._SubParsersAction) -> argparse.ArgumentParser:  # type: ignore[type-arg]
    p = sub.add_parser("calibrate", help="the run's system file with each real-code process a skeleton "
                       "computing what its code measured in the run")
    p.add_argument("run", type=Path, help="a run directory (its system.yaml and run.lcm)")
    p.add_argument("--out", type=Path, help="the system file to write (default RUN/calibrated.yaml); each "
                   "process's compute times go beside it, in OUT-STEM.compute/PROCESS.csv")
    return p


def measured_compute_us(records: np.ndarray, system: System) -> dict[int, np.ndarray]:
    """Per process of `system` that runs real code, its compute times (us) in the measured window
    of the run's first generation (the one `system` describes), its completed cycles only."""
    if not len(records):
        return {}
    first = records[records["generation"] == records["generation"].min()]
    kept = first[measured(first, system) & completed(first)]
    return {p.id: kept["compute_ns"][kept["process"] == p.id] / 1000.0
            for p in system.processes if p.code is not None}


def _samples_text(compute_us: np.ndarray) -> str:
    """A samples file: the table the file's loader makes of these times (compute.table_of_samples),
    so what the DPUs draw from is the same whether the file holds them all or the table."""
    return "compute_us\n" + "".join(f"{v:.3f}\n" for v in table_of_samples(compute_us.tolist()))


def calibrate_command(args: argparse.Namespace) -> int:
    log = run_log_path(args.run)
    source = log.parent / "system.yaml"
    system = load(source)
    coded = [p for p in system.processes if p.code is not None]
    if not coded:
        raise CalibrateError(f"{source}: no process runs real code (compute: {{library: ...}}): "
                             "nothing to calibrate")
    times = measured_compute_us(load_records(open_run_log(log)).records, system)
    for p in coded:
        if not len(times.get(p.id, ())):
            raise CalibrateError(f"{log}: {p.name} completed no cycle in the run's measured window: "
                                 "nothing measured to calibrate it with")
    out = args.out or log.parent / "calibrated.yaml"
    folder = out.parent / f"{out.stem}.compute"
    text = system.source_text
    for p in coded:
        item = yamledit.process_item(yamledit.root(text), p.name)
        if item is None:
            raise CalibrateError(f"{source}: processes.{p.name} is not spelled out as a mapping to edit")
        relative = f"{folder.name}/{p.name}.csv"
        text = yamledit.apply(text, [yamledit.set_key(text, item, "compute_us", f"{{samples: {relative}}}")])
        removed = yamledit.remove_key(text, yamledit.process_item(yamledit.root(text), p.name) or item,
                                      "compute")
        text = yamledit.apply(text, [removed] if removed else [])
    folder.mkdir(parents=True, exist_ok=True)
    for p in coded:
        (folder / f"{p.name}.csv").write_text(_samples_text(times[p.id]))
    loads(text, out)  # what is written loads: the samples beside it are already there
    out.write_text(text)
    columns = [("process", False), ("assumed µs", True), ("p50 µs", True), ("p99 µs", True),
               ("max µs", True), ("cycles", True), ("samples", False)]
    rows = [[p.name, f"{p.compute_us:.0f}", f"{np.percentile(times[p.id], 50):.1f}",
             f"{np.percentile(times[p.id], 99):.1f}", f"{times[p.id].max():.1f}", str(len(times[p.id])),
             str(folder / f"{p.name}.csv")] for p in coded]
    table = make_table("real code measured, now the skeleton's compute", columns, rows)
    console = output_console()
    console.print(table)
    print(f"wrote {out}: {len(coded)} process(es) calibrated; run it as a skeleton: skel run {out} --spawn")
    return 0
