"""The `skel` command line as a user or a script meets it: `skel status` hears every DPU that
is up, Ctrl-C and SIGTERM end every command the same way (exit 130, `skel run` keeping its
report), output to a file or pipe keeps every column, and the exit codes are the documented ones."""

from __future__ import annotations

import fcntl
import io
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
from analysis_synth import batches, report, small_config, small_run, status, write_log
from conftest import EXAMPLES, REPO, skel
from rich.console import Console

from skeleton.analysis import errors
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.console import UNLIMITED_WIDTH
from skeleton.analysis.views.tables import print_report, process_table
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL

PAIR = EXAMPLES / "pair-10ms-5ms.yaml"
# What an interpreter prints when an exception escapes at the wrong moment.
DUMP = re.compile(r"Traceback|object repr|lost sys\.stderr|Exception ignored|Fatal Python error")


def test_status_with_nothing_up_says_how_long_it_listened(url: str) -> None:
    done = skel("status", "--url", url, "--wait", "3")
    assert done.returncode == errors.EXIT_FAILED, done.stdout + done.stderr
    assert re.search(r"no DPU heard on \S+ \(its record URL \S+\) in 1\.\d s", done.stdout), done.stdout


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
    done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", "report", str(log), "--all"],
                          cwd=REPO,
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


def test_exit_codes_are_defined_in_one_module() -> None:
    """host/ and analysis/ return the codes of analysis/errors.py, never their own."""
    definition = re.compile(r"^\s*(EXIT_\w+\s*(,\s*EXIT_\w+\s*)*=|return 13\d\b)", re.MULTILINE)
    found = {str(path.relative_to(REPO)): definition.findall(path.read_text())
             for folder in ("host", "analysis") for path in sorted((REPO / folder).rglob("*.py"))}
    elsewhere = {path: hits for path, hits in found.items() if hits and path != "analysis/errors.py"}
    assert not elsewhere, elsewhere
    assert (errors.EXIT_OK, errors.EXIT_FAILED, errors.EXIT_BAD_INPUT, errors.EXIT_FATAL_FLAW,
            errors.EXIT_INTERRUPTED) == (0, 1, 2, 3, 130)


@pytest.mark.parametrize(("args", "said"), [
    (["simulate", str(EXAMPLES / "code" / "sum.yaml")],
     "skel simulate: process source runs real code (compute: library sum), which virtual time cannot time: "
     "run it on DPUs (skel run --spawn --lib-dir DIR)"),
    (["run", str(EXAMPLES / "code" / "sum.yaml"), "--lib-dir", "build/examples"],
     "skel run: --lib-dir is for the DPUs --spawn starts: give it to skel-dpu (or skel up) instead"),
])
def test_real_code_where_it_cannot_run_is_one_line_and_exit_2(args: list[str], said: str) -> None:
    done = skel(*args)
    assert done.returncode == 2 and done.stderr == said + "\n", done.stdout + done.stderr
