"""tests/unit/test_cli.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

from conftest import REPO, SANITIZER_ERROR, DpuFarm, bound_udp_ports, skel
from unit.test_cli import DUMP, PAIR, _closed_pipe

from skeleton.analysis import errors
from skeleton.analysis.measure.run import load_run
from skeleton.host.live import spawn
from skeleton.host.live.control import Control
from skeleton.host.sysfile.link import parse_url, record_url


def _skel_popen(*args: str, env: dict[str, str] | None = None) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "skeleton.host.cli", *args], cwd=REPO, text=True,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, env=env or dict(os.environ))


# --- skel status ---------------------------------------------------------------------------------
def test_status_right_after_four_dpus_start_lists_all_four(dpus: DpuFarm, url: str) -> None:
    dpus.start(1, 2, 3, 4)
    done = skel("status", "--url", url, "--json")
    assert done.returncode == 0, done.stdout + done.stderr
    assert sorted(row["dpu"] for row in json.loads(done.stdout)) == [1, 2, 3, 4], done.stdout
    listened = re.search(r"listened (\d+\.\d) s on .* \(until no new DPU for 1 s, at most 5 s\)", done.stderr)
    assert listened, done.stderr
    assert 1.0 <= float(listened.group(1)) < 5.0, done.stderr


def test_status_lists_every_auto_dpu_not_one(url: str, tmp_path: Path) -> None:
    """DPUs started with --id auto all heartbeat as DPU -1 until a config names them: each is
    a row of its own (host and pid), not one row for all."""
    daemons = [spawn.start_dpu("auto", url, tmp_path / f"auto{i}") for i in range(3)]  # type: ignore[arg-type]
    try:
        done = skel("status", "--url", url, "--json")
        table = skel("status", "--url", url)
    finally:
        codes = [spawn.stop(d) for d in daemons]
    assert done.returncode == 0, done.stdout + done.stderr
    rows = json.loads(done.stdout)
    assert sorted(r["pid"] for r in rows) == sorted(d.process.pid for d in daemons), rows
    assert {(r["dpu"], r["state"]) for r in rows} == {(-1, "unconfigured")}, rows
    assert table.stdout.count("│ auto ") == 3, table.stdout
    for daemon, code in zip(daemons, codes, strict=True):
        log = daemon.log_path.read_bytes()
        assert not SANITIZER_ERROR.search(log) and code == 0, log.decode(errors="replace")


def test_spawn_is_refused_beside_an_auto_dpu_that_would_take_one(url: str, tmp_path: Path) -> None:
    """An --id auto daemon on this host takes the DPU the system gives its host name, once a
    config names it: --spawn starting that DPU too would run it twice."""
    system = tmp_path / "pair.yaml"
    system.write_text(PAIR.read_text().replace("  - {id: 1}", f"  - {{id: 1, host: {socket.gethostname()}}}"))
    daemon = spawn.start_dpu("auto", url, tmp_path / "auto")  # type: ignore[arg-type]
    try:
        done = skel("run", str(system), "--spawn", "--url", url, "--out", str(tmp_path / "run"))
    finally:
        code = spawn.stop(daemon)
    assert done.returncode == errors.EXIT_FAILED, done.stdout + done.stderr
    assert f"DPU 1 (pid {daemon.process.pid} on {socket.gethostname()}, started with --id auto) already up" \
        in done.stdout, done.stdout
    assert not (tmp_path / "run" / "logs").exists() and code == 0


# --- Ctrl-C and SIGTERM --------------------------------------------------------------------------
def _wait_running(url: str, timeout_s: float = 30.0) -> None:
    control = Control(url)
    try:
        assert control.wait_for(lambda: any(v.state == "running" for v in control.dpus.values()), timeout_s)
    finally:
        control.close()


def test_run_interrupted_by_ctrl_c_writes_its_report_and_exits_130(url: str, tmp_path: Path) -> None:
    out = tmp_path / "cut"
    run = _skel_popen("run", str(PAIR), "--spawn", "--url", url, "--duration", "30",
                      "-s", "run.warmup_cycles=5", "--out", str(out), "--all")
    _wait_running(url)
    time.sleep(1.5)
    run.send_signal(signal.SIGINT)
    stdout, stderr = run.communicate(timeout=60)
    assert run.returncode == errors.EXIT_INTERRUPTED == 130, stdout + stderr
    assert not DUMP.search(stderr), stderr
    assert "interrupted: stopping the run" in stdout, stdout
    assert "per process" in stdout and f"run written to {out}/" in stdout, stdout
    written = json.loads((out / "report.json").read_text())
    cycles = {p["name"]: p["cycles"] for p in written["processes"]}
    # Cut after a second or two of a 30 s run: the report covers what ran, no more.
    assert set(cycles) == {"slow_writer", "fast_writer", "fast_reader", "slow_reader"}, cycles
    assert 0 < cycles["fast_writer"] < 2000, cycles
    # The log alone says the run was cut short, and by whom: report.json is made from it.
    stopped = written["stopped"]
    assert stopped["command"] == "STOP" and stopped["planned_s"] == 30.0, stopped
    assert 0 < stopped["at_s"] < 20 and stopped["sender"].endswith(f"pid {run.pid}"), stopped


def test_watch_ended_by_sigterm_ends_as_by_ctrl_c(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    dpus.start(1, 2)
    run = _skel_popen("run", str(PAIR), "--url", url, "--duration", "12", "--out", str(tmp_path / "run"))
    try:
        _wait_running(url)
        # Following a run: messages arrive all the time, so the signal lands inside LCM's wait.
        watchers = {("--once", signal.SIGTERM): _skel_popen("watch", "--url", url, "--once"),
                    ("live", signal.SIGTERM): _skel_popen("watch", "--url", url),
                    ("--once", signal.SIGINT): _skel_popen("watch", "--url", url, "--once")}
        # Each once it listens (a loaded machine took more than 2.5 s to import it: killed
        # before main() had its handler, one ended with -15), then a while into its wait.
        port = parse_url(record_url(url)).port  # where a watcher hears the run
        deadline = time.monotonic() + 60
        while not all(w.poll() is None and port in bound_udp_ports(w.pid) for w in watchers.values()):
            ended = {mode: w.communicate() for mode, w in watchers.items() if w.poll() is not None}
            assert not ended and time.monotonic() < deadline, f"a watcher never listened: {ended}"
            time.sleep(0.1)
        time.sleep(1.0)
        for (_, signum), watcher in watchers.items():
            watcher.send_signal(signum)
        for (mode, signum), watcher in watchers.items():
            _, stderr = watcher.communicate(timeout=30)
            what = f"watch {mode} ended by {signal.Signals(signum).name}: exit {watcher.returncode}\n{stderr}"
            assert watcher.returncode == errors.EXIT_INTERRUPTED, what
            assert not DUMP.search(stderr), what
    finally:
        run.send_signal(signal.SIGTERM)
        run.communicate(timeout=60)


def test_a_run_whose_reader_goes_away_runs_to_its_report(url: str, tmp_path: Path) -> None:
    """`skel run FILE | grep -m1 FAULT`: the run goes on quietly, stops its DPUs and keeps its
    log and report; the command then ends with 141."""
    out = tmp_path / "run"
    write_end = _closed_pipe()
    args = ["run", str(PAIR), "--spawn", "--url", url, "--duration", "2", "-s", "run.warmup_cycles=5",
            "--out", str(out)]
    run = subprocess.run([sys.executable, "-m", "skeleton.host.cli", *args], cwd=REPO, stdout=write_end,
                         stderr=subprocess.PIPE, text=True, timeout=120)  # fmt: skip
    os.close(write_end)
    assert run.returncode == errors.EXIT_BROKEN_PIPE, run.stderr
    assert not DUMP.search(run.stderr) and "warning:" not in run.stderr, run.stderr  # DPUs ended well
    cycles = {p["name"]: p["cycles"] for p in json.loads((out / "report.json").read_text())["processes"]}
    assert set(cycles) == {"slow_writer", "fast_writer", "fast_reader", "slow_reader"}, cycles
    assert min(cycles.values()) > 0, cycles
    assert len(load_run(out / "run.lcm").records) > 0
