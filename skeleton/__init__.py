"""The public Python API of skeleton, for scripts and notebooks over recorded runs.

    import skeleton
    run = skeleton.load_run("runs/servo")     # a run directory, its run.lcm, or an .mcap export
    run.report                # the typed report (what report.json holds)
    run.dpus.to_pandas()      # its per-DPU rows; also run.processes
    run.timing.to_pandas()    # one row per process cycle; also .to_arrow()
    run.receptions, run.faults
    skeleton.compare(run_a, run_b)   # what `skel diff --json` prints

What is exported here is kept stable; everything else may change between versions.
"""

from __future__ import annotations

from skeleton.analysis.measure.columns import COLUMNS, Table
from skeleton.analysis.measure.run import RunAnalysis, load_run
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.views.diff import compare

__all__ = ["COLUMNS", "LogError", "RunAnalysis", "Table", "compare", "load_run"]
