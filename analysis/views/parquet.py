"""`skel export RUN --parquet DIR`: the run's tables (measure/columns.py) as Parquet,
one file per table, for pandas, polars, DuckDB or Spark. Each file's schema carries the
column descriptions and the run it came from (metadata key "skeleton")."""

from __future__ import annotations

import json
from pathlib import Path

import pyarrow.parquet as pq

from ..measure.run import RunAnalysis
from .outfile import replaced


def write_parquet(run: RunAnalysis, out_dir: Path) -> dict[str, int]:
    """DIR/<table>.parquet for every table; returns rows per table."""
    out_dir.mkdir(parents=True, exist_ok=True)
    about = json.dumps({"system": run.report.system, "run_id": run.report.run_id,
                        "generation": run.report.generation, "source": run.path}).encode()  # fmt: skip
    rows = {}
    for name, table in run.tables().items():
        arrow = table.to_arrow()
        arrow = arrow.replace_schema_metadata({**(arrow.schema.metadata or {}), b"skeleton": about})
        with replaced(out_dir / f"{name}.parquet") as part:
            pq.write_table(arrow, part)
        rows[name] = len(table)
    return rows
