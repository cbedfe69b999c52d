"""`skel export RUN [RUN.mcap] [--parquet DIR] [--trace FILE.json]`: the run read once,
then written in each format asked for (MCAP for Foxglove, Parquet tables, a Perfetto trace)."""

from __future__ import annotations

import sys
from pathlib import Path

from ..errors import EXIT_BAD_INPUT, EXIT_OK
from ..measure.run import load_run
from ..read.messages import LogError
from .export_mcap import export
from .parquet import write_parquet
from .trace import write_trace


def export_command(log: Path, mcap: Path | None, run_id: int | None, parquet: Path | None = None,
                   trace: Path | None = None, key: bytes | None = None) -> int:
    """0, or 2 with one line when the log cannot be read or an output written."""
    if mcap is None and parquet is None and trace is None:
        print(f"{log}: nothing to write: name an .mcap file, --parquet DIR or --trace FILE.json",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    if mcap is not None and Path(log).suffix == ".mcap":
        print(f"{log}: already an MCAP file; the MCAP export reads an LCM log (run.lcm)", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        run = load_run(log, run_id, key)
    except LogError as e:
        print(f"{log}: {e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    target = None
    try:
        if mcap is not None:
            target = mcap
            counts = export(run, mcap)
            print(f"{mcap}: run {run.report.run_id}, {counts['timing']} timing records, "
                  f"{counts['messages']} messages on {counts['topics']} topics")  # fmt: skip
        if parquet is not None:
            target = parquet
            rows = write_parquet(run, parquet)
            print(f"{parquet}/: run {run.report.run_id}, " + ", ".join(f"{n}.parquet {r} rows"
                                                                     for n, r in rows.items()))
        if trace is not None:
            target = trace
            events = write_trace(run, trace)
            print(f"{trace}: run {run.report.run_id}, {events} trace events (open in ui.perfetto.dev)")
    except OSError as e:
        print(f"{target}: {e.strerror or e}", file=sys.stderr)
        return EXIT_BAD_INPUT
    return EXIT_OK
