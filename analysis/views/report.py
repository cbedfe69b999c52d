"""`skel report RUN [--all] [--json] [--run N] [--plots DIR]`: the run read once, its prediction
laid beside it when the host tool gives a predictor, and the simulation `skel run` left beside
it (RUN/simulated/), then one screen of it (every table with --all, or report.json on stdout)
and, when asked, its plots and report.html."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from ..errors import EXIT_BAD_INPUT, EXIT_FATAL_FLAW, EXIT_OK
from ..measure.predicted import Predictor
from ..measure.run import RunAnalysis, load_run
from ..read.messages import LogError
from .summary import print_summary
from .tables import print_report


def report_command(path: str | os.PathLike[str], as_json: bool, run_id: int | None,
                   plots: Path | None = None, predictor: Predictor | None = None,
                   key: bytes | None = None, all_tables: bool = False) -> int:
    """0, 3 on a fatal flaw, 2 with one line when the log cannot be read or a plot written."""
    try:
        run = load_run(path, run_id, key)
    except LogError as e:
        print(f"{path}: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    missing = run.add_prediction(predictor) if predictor is not None else None
    if missing:
        print(f"{path}: {missing}", file=sys.stderr)
    simulated = Path(path).parent / "simulated" / "run.lcm"
    if not run.report.simulated and simulated.exists():
        try:
            run.add_simulation(load_run(simulated).report, os.fspath(simulated.parent))
        except LogError as e:
            print(f"{simulated}: no simulation beside the run: {e}", file=sys.stderr)
    if as_json:
        json.dump(run.report.to_json(), sys.stdout, indent=2)
        sys.stdout.write("\n")
    elif all_tables:
        print_report(run.report)
    else:
        print_summary(run.report, where=os.fspath(path))
    if plots is not None:
        try:
            write_plot_dir(run, plots, source=os.fspath(path))
        except OSError as e:
            print(f"{plots}: {e.strerror or e}", file=sys.stderr)
            return EXIT_BAD_INPUT
    return EXIT_FATAL_FLAW if run.report.fatal else EXIT_OK


def write_plot_dir(run: RunAnalysis, out_dir: Path, source: str) -> None:
    # Imported here: matplotlib takes most of a second to import, which a report without
    # plots (most of them, and every `skel report --json`) should not pay.
    from .html import write_html
    from .plots import write_plots

    out_dir.mkdir(parents=True, exist_ok=True)
    made = write_plots(run, out_dir)
    page = write_html(run, made, out_dir, source=source)
    # stderr: `skel report --json --plots DIR` keeps stdout pure JSON
    print(f"plots: {len(made.plots)} PNG and {page.name} written to {out_dir}/", file=sys.stderr)
