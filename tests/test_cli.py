"""The `skel` command line as a user or a script meets it: `skel status` hears every DPU that
is up, Ctrl-C and SIGTERM end every command the same way (exit 130, `skel run` keeping its
report), output to a file or pipe keeps every column, and the exit codes are the documented ones."""

from __future__ import annotations

import fcntl
import io
import json
import os
import re
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from analysis_synth import batches, report, small_config, small_run, status, write_log
from conftest import EXAMPLES, REPO, SANITIZER_ERROR, DpuFarm, skel
from rich.console import Console

from skeleton.analysis import errors
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.console import UNLIMITED_WIDTH
from skeleton.analysis.views.tables import print_report, process_table
from skeleton.host.live import spawn
from skeleton.host.live.control import Control
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL

PAIR = EXAMPLES / "pair-10ms-5ms.yaml"
# What an interpreter prints when an exception escapes at the wrong moment.
DUMP = re.compile(r"Traceback|object repr|lost sys\.stderr|Exception ignored|Fatal Python error")


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


def test_status_with_nothing_up_says_how_long_it_listened(url: str) -> None:
    done = skel("status", "--url", url, "--wait", "3")
    assert done.returncode == errors.EXIT_FAILED, done.stdout + done.stderr
    assert re.search(r"no DPU heard on \S+ \(its record URL \S+\) in 1\.\d s", done.stdout), done.stdout


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
                      "-s", "run.warmup_cycles=5", "--out", str(out))
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
        time.sleep(2.5)
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


# --- output to a file or a pipe ------------------------------------------------------------------
def _wide_log(path: Path) -> Path:
    """A synthetic run whose process names make the per-process table wider than 80 columns."""
    dpu1, dpu2 = small_run()
    config = small_config()
    for process in config.processes:
        process.name = f"{process.name}_a_process_name_of_thirty_chars"
    t1, t2 = batches(1, dpu1, 4), batches(2, dpu2, 2)
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, config)]
    events += [(TIMING_CHANNEL, t) for t in t1 + t2]
    events += [(STATUS_CHANNEL, status(1, [])), (STATUS_CHANNEL, status(2, []))]
    events += [(REPORT_CHANNEL, report(1, len(t1))), (REPORT_CHANNEL, report(2, len(t2)))]
    return write_log(path, events)


def test_tables_through_a_pipe_keep_every_column(tmp_path: Path) -> None:
    log = _wide_log(tmp_path / "run.lcm")
    env = {k: v for k, v in os.environ.items() if k not in ("COLUMNS", "LINES")}
    done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", "report", str(log)], cwd=REPO,
                          capture_output=True, text=True, env=env, timeout=60)
    assert done.returncode == 0, done.stderr
    rep = load_run(str(log), None).report
    wide = Console(file=io.StringIO(), width=UNLIMITED_WIDTH)
    print_report(rep, console=wide)
    assert done.stdout == wide.file.getvalue()  # type: ignore[attr-defined]
    widest = max(len(line) for line in done.stdout.splitlines())
    assert widest > 80, "the test needs a table wider than rich's default 80 columns"
    for column in process_table(rep).columns:
        for word in str(column.header).split("\n"):
            assert word in done.stdout, f"column {column.header!r} lost:\n{done.stdout}"


# --- exit codes ------------------------------------------------------------------------------------
def test_a_reader_that_stops_early_ends_the_report_without_a_traceback(tmp_path: Path) -> None:
    log = _wide_log(tmp_path / "run.lcm")
    read_end, write_end = os.pipe()
    fcntl.fcntl(write_end, fcntl.F_SETPIPE_SZ, 4096)  # the report (~50 kB) cannot all fit in it
    report = subprocess.Popen([sys.executable, "-m", "skeleton.host.cli", "report", str(log), "--json"],
                              cwd=REPO, stdout=write_end, stderr=subprocess.PIPE)  # fmt: skip
    os.close(write_end)
    assert os.read(read_end, 1) == b"{"
    os.close(read_end)  # as `| head -c 1` does
    assert report.wait(timeout=60) == errors.EXIT_BROKEN_PIPE
    assert report.stderr is not None and b"Traceback" not in report.stderr.read()


def _closed_pipe() -> int:
    """The write end of a pipe nobody reads (`| true`): every write to it fails."""
    read_end, write_end = os.pipe()
    os.close(read_end)
    return write_end


@pytest.mark.parametrize("args", [["check", str(PAIR), "--json"], ["check", str(PAIR)], ["--help"]],
                         ids=["print", "rich", "argparse"])
def test_a_reader_gone_before_a_short_output_ends_the_command_with_141(args: list[str]) -> None:
    """Output smaller than stdout's buffer is written when Python flushes it at exit, outside
    any handler ("Exception ignored", exit 120), and rich's console exits with 1 on its own."""
    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # the buffer as a user has it
    write_end = _closed_pipe()
    done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", *args], cwd=REPO, stdout=write_end,
                          stderr=subprocess.PIPE, text=True, env=env, timeout=60)  # fmt: skip
    os.close(write_end)
    assert done.returncode == errors.EXIT_BROKEN_PIPE, done.stderr
    assert not DUMP.search(done.stderr), done.stderr


def test_skel_watch_ends_when_its_reader_goes_away(url: str) -> None:
    """`skel watch | head`: piped, the view is drawn once, when it stops; a reader gone
    before then ends the watch (at its next refresh), which changes no run."""
    write_end = _closed_pipe()
    argv = [sys.executable, "-m", "skeleton.host.cli", "watch", "--url", url, "--duration", "120"]
    watch = subprocess.Popen(argv, cwd=REPO, stdout=write_end, stderr=subprocess.PIPE)
    os.close(write_end)
    assert watch.wait(timeout=60) == errors.EXIT_BROKEN_PIPE
    assert watch.stderr is not None and not DUMP.search(watch.stderr.read().decode())


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


def test_exit_codes_are_defined_in_one_module() -> None:
    """host/ and analysis/ return the codes of analysis/errors.py, never their own."""
    definition = re.compile(r"^\s*(EXIT_\w+\s*(,\s*EXIT_\w+\s*)*=|return 13\d\b)", re.MULTILINE)
    found = {str(path.relative_to(REPO)): definition.findall(path.read_text())
             for folder in ("host", "analysis") for path in sorted((REPO / folder).rglob("*.py"))}
    elsewhere = {path: hits for path, hits in found.items() if hits and path != "analysis/errors.py"}
    assert not elsewhere, elsewhere
    assert (errors.EXIT_OK, errors.EXIT_FAILED, errors.EXIT_BAD_INPUT, errors.EXIT_FATAL_FLAW,
            errors.EXIT_INTERRUPTED) == (0, 1, 2, 3, 130)
