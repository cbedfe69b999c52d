"""Compare one process's response time in two runs, with the skeleton Python API.

    .venv/bin/python examples/analysis.py RUN_A RUN_B [--process NAME] [--out PNG]

RUN_A and RUN_B are run directories (`skel run --out DIR`), run.lcm logs or MCAP exports,
e.g. the same system before and after moving a process to another DPU. Prints each run's
p50 / p99 response time of the process (the report's definition: end of the cycle's work
minus its release, over the measured cycles) and plots it cycle by cycle in both, by
default into RUN_B's directory as response-NAME.png.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # files only, no display needed
import matplotlib.pyplot as plt

import skeleton


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("runs", nargs=2, type=Path)
    parser.add_argument("--process", default="jacobian_transpose")
    parser.add_argument("--out", type=Path)
    args = parser.parse_args()
    # Beside the run it is about, not in whatever directory the script was started from.
    where = args.runs[1] if args.runs[1].is_dir() else args.runs[1].parent
    out = args.out or where / f"response-{args.process}.png"

    fig, ax = plt.subplots(figsize=(9, 4))
    runs = [skeleton.load_run(path) for path in args.runs]
    for path, run in zip(args.runs, runs, strict=True):
        cycles = run.timing.to_pandas()
        # The report's window: the timing table holds every generation of a run pushed mid-way.
        mine = cycles[(cycles.process_name == args.process) & (cycles.generation == run.report.generation)
                      & cycles.measured & cycles.completed]
        p50, p99 = mine.response_us.quantile([0.5, 0.99])
        print(f"{path}: {args.process} response p50 {p50:.1f} us, p99 {p99:.1f} us "
              f"over {len(mine)} cycles")
        ax.plot(mine.cycle, mine.response_us, lw=0.8, label=f"{path.name} (run {run.report.run_id})")
    diff = skeleton.compare(*runs)
    faults = [len(run.report.faults) for run in runs]
    print(f"faults: {faults[0]} and {faults[1]}; {len(diff['processes'])} processes compared")
    ax.set(xlabel="cycle", ylabel="response time (µs)", title=f"{args.process}: response time")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out, dpi=100)
    print(f"plot: {out}")


if __name__ == "__main__":
    main()
