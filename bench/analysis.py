"""`make bench` part analysis: the analysis and the export on a run of 10^7 records.

A real SERVO run of a few seconds (local DPUs, ttl=0) is grown into one long run of
RECORDS timing records (bench/biglog.py), then timed as a user runs it, each command a
process of its own (wall clock and peak memory from wait4):

  skel report LOG --json        goal: 10 s and 2 GiB for 10^7 records
  skel export LOG RUN.mcap      goal: 10^6 records/s, the whole command
  and, in this process, export_mcap.export alone on the run already read (the MCAP
  writing, without the reading and the analysis the command starts with).

`skel watch` refreshing incrementally (the issue's last goal) is not built: printed as such.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from biglog import grow  # bench/biglog.py, beside this file

from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.export_mcap import export

REPO = Path(__file__).resolve().parent.parent
SERVO = REPO / "examples" / "servo.yaml"
REPORT_S, REPORT_GIB, EXPORT_PER_S = 10.0, 2.0, 1_000_000


def _timed(argv: list[str]) -> tuple[float, float]:
    """(wall s, peak resident GiB) of one command, its output discarded."""
    start = time.monotonic()
    with tempfile.TemporaryFile() as err:  # a pipe read only after the exit could fill and block it
        proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=err, cwd=REPO)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.monotonic() - start
        if os.waitstatus_to_exitcode(status) not in (0, 3):
            err.seek(0)
            raise SystemExit(f"bench: {' '.join(argv)} failed: {err.read().decode(errors='replace')}")
    return wall, usage.ru_maxrss / 2**20


def part_analysis(tmp: Path, url: str, records: int) -> list[str]:
    source = tmp / "servo-source"
    run = [sys.executable, "-m", "skeleton.host.cli", "run", str(SERVO), "--spawn", "--url", url,
           "--duration", "5", "--out", str(source)]  # fmt: skip
    done = subprocess.run(run, capture_output=True, text=True, timeout=120, cwd=REPO,
                          env={**os.environ, "SKEL_DPU": str(REPO / "build" / "skel-dpu")})  # fmt: skip
    if done.returncode not in (0, 3):
        raise SystemExit(f"bench: the SERVO source run failed:\n{done.stdout}{done.stderr}")
    log = tmp / "long.lcm"
    held = grow(source / "run.lcm", log, records)
    skel = [sys.executable, "-m", "skeleton.host.cli"]
    report_s, report_gib = _timed([*skel, "report", str(log), "--json"])
    export_s, export_gib = _timed([*skel, "export", str(log), str(tmp / "long.mcap")])
    analysed = load_run(log)
    start = time.monotonic()
    export(analysed, tmp / "again.mcap")
    write_s = time.monotonic() - start
    mb = log.stat().st_size / 1e6
    ok_report = report_s <= REPORT_S * held / 1e7 and report_gib <= REPORT_GIB * max(1.0, held / 1e7)
    ok_export = held / export_s >= EXPORT_PER_S
    return [
        f"analysis: {held:,} records ({mb:.0f} MB of log): skel report {report_s:.1f} s, "
        f"{report_gib:.2f} GiB: {'PASS' if ok_report else 'FAIL'}; skel export "
        f"{held / export_s / 1e3:.0f} k records/s: {'PASS' if ok_export else 'FAIL'}; "
        f"skel watch incremental: not built, FAIL",
        f"  goals (scaled to {held:,} records): report within {REPORT_S * held / 1e7:.1f} s and "
        f"{REPORT_GIB * max(1.0, held / 1e7):.1f} GiB; export at {EXPORT_PER_S:,} records/s",
        f"  skel export: {export_s:.1f} s, {export_gib:.2f} GiB; of it the MCAP writing alone "
        f"{write_s:.1f} s ({held / write_s / 1e3:.0f} k records/s), the rest reading and analysing",
        f"  MCAP {(tmp / 'long.mcap').stat().st_size / 1e6:.0f} MB (zstd chunks; the source log attached "
        f"whole)",
    ]
