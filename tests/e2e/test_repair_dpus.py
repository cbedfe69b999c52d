"""A logger that misses messages: `skel run` asks the DPUs again, and the log ends up whole.

lcm-logger drops what arrives while its process is not scheduled (the kernel's socket
buffer, then LCM's queue of 30). Here it is stopped outright for two seconds of a busy
run (real DPUs, real logger, real multicast with ttl=0): the holes must be filled.
"""

from __future__ import annotations

import json
import os
import signal
import time
from pathlib import Path

from conftest import Background, skel_background

from skeleton.host.live.repair import RESTARTS_MAX
from skeleton.host.live.spawn import running

# Two DPUs, 1000 records a second each: ~20 timing batches a second of ~4.5 kB (four
# datagrams), ~250 kB/s of the logger's socket buffer (net.core.rmem_default, 208 kB
# here): stopped for three times what that buffer holds, the logger must lose some.
BYTES_PER_S = 250_000
BUSY_SYSTEM = """\
system: busy
dpus: [{id: 1, compute: sleep}, {id: 2, compute: sleep}]
processes:
  - {id: 1, name: a1, dpu: 1, period_us: 2000, compute_us: 100}
  - {id: 2, name: b1, dpu: 1, period_us: 2000, compute_us: 100}
  - {id: 3, name: a2, dpu: 2, period_us: 2000, compute_us: 100}
  - {id: 4, name: b2, dpu: 2, period_us: 2000, compute_us: 100}
run: {warmup_cycles: 10, lockout_cycles: 200}
"""


def _logger_pid(log: Path, timeout_s: float) -> int:
    """The real lcm-logger binary writing `log` (not the `timeout` that wraps it)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        for pid, argv in running("lcm-logger").items():
            if str(log).encode() in argv:
                return pid
        time.sleep(0.05)
    raise AssertionError(f"no lcm-logger writing {log} within {timeout_s} s")


def _start_busy_run(tmp_path: Path, url: str, duration_s: int) -> tuple[Background, Path]:
    """A real `skel run --spawn` of BUSY_SYSTEM in the background, and its run directory."""
    system = tmp_path / "busy.yaml"
    system.write_text(BUSY_SYSTEM)
    out = tmp_path / "busy"
    return skel_background("run", str(system), "--spawn", "--url", url, "--duration", str(duration_s),
                           "--out", str(out)), out


def test_run_refills_what_a_stalled_logger_missed(tmp_path: Path, url: str) -> None:
    rmem = int(Path("/proc/sys/net/core/rmem_default").read_text())
    stopped_s = min(20.0, max(2.0, 3 * rmem / BYTES_PER_S))
    duration_s = int(stopped_s) + 3
    run, out = _start_busy_run(tmp_path, url, duration_s)
    try:
        pid = _logger_pid(out / "run.lcm", 30)
        # Not a fixed wait after the logger appeared: a logger stopped before the run began misses
        # nothing (CI once, 2 s after it appeared).
        run.wait_started(lambda: (out / "logs").glob("dpu*.log"), 2)
        time.sleep(1.0)  # a second of the run
        os.kill(pid, signal.SIGSTOP)
        time.sleep(stopped_s)
        os.kill(pid, signal.SIGCONT)
        code = run.wait(60 + duration_s)
    finally:
        if run.proc.poll() is None:
            run.proc.kill()
    assert code == 0, run.output
    # The stop did cost the logger messages (else this test proves nothing) ...
    assert "the logger missed" in run.output and "all logged" in run.output, run.output
    resent = [line for f in (out / "logs").glob("*.log") for line in f.read_text().splitlines()
              if "re-sent" in line]
    assert resent, "no DPU was asked to re-send"
    # ... and the log holds every batch and every cycle all the same.
    report = json.loads((out / "report.json").read_text())
    assert report["integrity"]["lost_batches"] == [], report["integrity"]
    expected = duration_s * 500 - 10
    short = {p["name"]: p["cycles"] for p in report["processes"] if p["cycles"] < expected - 2}
    assert len(report["processes"]) == 4 and not short, short


def _kill_loggers(log: Path, count: int, first_after_s: float, timeout_s: float) -> int:
    """SIGKILL the real lcm-logger writing `log`, `count` times (each new one as it appears)."""
    killed = 0
    deadline = time.monotonic() + timeout_s
    time.sleep(first_after_s)
    while killed < count and time.monotonic() < deadline:
        try:
            pid = _logger_pid(log, max(0.1, deadline - time.monotonic()))
        except AssertionError:
            break
        os.kill(pid, signal.SIGKILL)
        killed += 1
        while Path(f"/proc/{pid}").exists() and time.monotonic() < deadline:
            time.sleep(0.01)  # reaped by its `timeout` wrapper: then look for the next one
    return killed


def _busy_run_killing_loggers(tmp_path: Path, url: str, duration_s: int, kills: int,
                              until_s: float) -> tuple[int, str, Path]:
    """A real `skel run --spawn` of BUSY_SYSTEM whose loggers are killed `kills` times, the
    first a second after the run started: its exit code, output, run dir."""
    run, out = _start_busy_run(tmp_path, url, duration_s)
    try:
        _logger_pid(out / "run.lcm", 30)
        run.wait_started(lambda: (out / "logs").glob("dpu*.log"), 2)
        assert _kill_loggers(out / "run.lcm", kills, 1.0, until_s) == kills
        code = run.wait(60 + duration_s)
    finally:
        if run.proc.poll() is None:
            run.proc.kill()
    return code, run.output, out


def test_run_restarts_a_killed_logger_and_the_log_holds_every_cycle(tmp_path: Path, url: str) -> None:
    duration_s = 6
    code, output, out = _busy_run_killing_loggers(tmp_path, url, duration_s, 1, 20)
    assert code == 0, output
    assert "the logger died (exit status" in output and "restarted it" in output, output
    assert "INCOMPLETE" not in output, output
    report = json.loads((out / "report.json").read_text())
    assert report["integrity"]["lost_batches"] == [] and report["integrity"]["corrupt_ranges"] == []
    expected = duration_s * 500 - 10
    short = {p["name"]: p["cycles"] for p in report["processes"] if p["cycles"] < expected - 2}
    assert len(report["processes"]) == 4 and not short, short


def test_a_log_that_cannot_be_made_whole_is_said_first_and_fails(tmp_path: Path, url: str) -> None:
    duration_s = 8
    # Every logger killed as soon as it is up: the host tool gives up after RESTARTS_MAX.
    code, output, _ = _busy_run_killing_loggers(tmp_path, url, duration_s, RESTARTS_MAX + 1, duration_s)
    assert code == 1, output
    assert f"the logger died {RESTARTS_MAX + 1} times" in output, output
    # Said before the tables, not under them.
    first_table = output.index("per DPU") if "per DPU" in output else len(output)
    assert -1 < output.find("INCOMPLETE") < first_table, output
