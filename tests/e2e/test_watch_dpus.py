"""tests/unit/test_watch.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import dataclasses
import difflib
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest
from conftest import EXAMPLES, LOCKOUT_SYSTEM, LOGPLAYER, REPO, fresh_url, short_servo_run, skel, threads_cpus
from unit.test_watch import _same_tables

from skeleton.analysis.measure.run import load_run
from skeleton.analysis.measure.tally import RunTally
from skeleton.analysis.read.logreader import read_log
from skeleton.host.cli.watch import Heard
from skeleton.host.sysfile.link import record_url

ENV = {**os.environ, "COLUMNS": "160"}



def _watch(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "skeleton.host.cli", "watch", *args], cwd=REPO, env=ENV,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _replay_and_compare(log: Path, url: str) -> tuple[subprocess.CompletedProcess[str], str, str]:
    """Replay `log` on a private URL while `skel watch --once` listens there. A replay
    is UDP too: when the watch itself reports batches lost on the way (a machine
    flooded by other tests), that replay proves nothing, and it is replayed once more."""
    report, out, err = _replay_once(log, fresh_url())
    if out != report.stdout and "timing batches lost" in out:
        report, out, err = _replay_once(log, fresh_url())
    return report, out, err


def _replay_once(log: Path, replay_url: str) -> tuple[subprocess.CompletedProcess[str], str, str]:
    watch = _watch("--once", "--all", "--url", replay_url, "--duration", "60")
    assert watch.stderr is not None
    ready = watch.stderr.readline()  # printed once subscribed: nothing of the replay is missed
    assert "waiting for a run" in ready, ready
    # The watch hears the record URL of its --url, as the logger does (host/sysfile/link.py).
    player = subprocess.run([str(LOGPLAYER), "-s", "1", "-l", record_url(replay_url), str(log)],
                            capture_output=True, text=True, timeout=60)
    assert player.returncode == 0, player.stderr
    out, err = watch.communicate(timeout=60)
    report = skel("report", str(log), "--all")   # every table, both
    return report, out, ready + err + f"\n(exit {watch.returncode})"


def test_replayed_run_gives_report_tables(tmp_path: Path, url: str) -> None:
    out = tmp_path / "pair"
    run = skel("run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--spawn", "--url", url, "--duration", "1.5",
               "-s", "run.warmup_cycles=10", "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    report, watched, err = _replay_and_compare(out / "run.lcm", url)
    assert report.returncode == 0, report.stderr
    assert "following run" in err, err
    assert "(exit 0)" in err, err
    assert "slow_writer" in watched and "per DPU" in watched, watched + err
    assert watched == report.stdout, _diff(report.stdout, watched, err)


def _diff(expected: str, got: str, err: str) -> str:
    lines = difflib.unified_diff(expected.splitlines(), got.splitlines(), "skel report", "skel watch --once")
    return "\n".join(lines) + "\n" + err


def test_replayed_lockout_exits_3_with_the_same_tables(tmp_path: Path, url: str) -> None:
    system = tmp_path / "lockout.yaml"
    system.write_text(LOCKOUT_SYSTEM)
    out = tmp_path / "lock"
    run = skel("run", str(system), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode == 3, run.stdout + run.stderr
    report, watched, err = _replay_and_compare(out / "run.lcm", url)
    assert report.returncode == 3 and "(exit 3)" in err, err
    assert "hungry_reader" in watched and "lockout" in watched, watched + err
    assert watched == report.stdout, _diff(report.stdout, watched, err)


def test_live_view_shows_dpus_processes_and_lockout(tmp_path: Path, url: str) -> None:
    system = tmp_path / "lockout.yaml"
    system.write_text(LOCKOUT_SYSTEM)
    watch = _watch("--url", url, "--duration", "12")
    time.sleep(1.0)  # the watch subscribes before the run's DPUs even start
    run = skel("run", str(system), "--spawn", "--url", url, "--out", str(tmp_path / "lock"))
    assert run.returncode == 3, run.stdout + run.stderr
    shown, err = watch.communicate(timeout=30)
    assert watch.returncode == 0, err
    run_id = re.search(r"run (\d+), generation", run.stdout)
    assert run_id, run.stdout
    assert f"run {run_id.group(1)}" in shown, shown
    assert "per DPU" in shown and "per process" in shown, shown
    for row in (r"│\s+1 │", r"│\s+2 │"):  # one row per DPU
        assert re.search(row, shown), shown
    assert "slow_writer" in shown and "hungry_reader" in shown, shown
    assert "lockout: hungry_reader (DPU 2)" in shown, shown


def test_the_live_view_keeps_off_the_cpus_its_hosts_dpus_are_pinned_to(tmp_path: Path, url: str) -> None:
    """As `skel run` does (test_run): a `skel watch` on a DPU's machine moves every thread of
    it off the CPU that DPU is pinned to once it hears the run's config."""
    allowed = os.sched_getaffinity(0)
    if len(allowed) < 2:
        pytest.skip("one CPU: nowhere else to go")
    pinned = min(allowed)
    out = tmp_path / "pinned"
    run = skel("run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--spawn", "--url", url, "--duration", "1.5",
               "-s", f"dpu.1.cpu={pinned}", "--out", str(out))
    # Only the log matters here (its config names the pinned CPU): a run the platform stalled
    # into a lockout (exit 3; CI once: 236.8 ms at 0.13 s) is as good a log to replay.
    assert run.returncode in (0, 3) and (out / "run.lcm").is_file(), run.stdout + run.stderr
    replay_url = fresh_url()
    watch = _watch("--url", replay_url, "--duration", "60")
    player: subprocess.Popen[bytes] | None = None
    try:
        deadline = time.monotonic() + 30
        now = threads_cpus(watch.pid)
        while len(now) < 2:  # the search for faults, in a thread of its own: subscribed by then
            assert time.monotonic() < deadline and watch.poll() is None, now
            time.sleep(0.05)
            now = threads_cpus(watch.pid)
        time.sleep(1.0)  # the view refreshed with nothing heard: it keeps every CPU
        now = threads_cpus(watch.pid)
        assert all(cpus == allowed for cpus in now.values()), now
        replay = [str(LOGPLAYER), "-s", "1", "-l", record_url(replay_url), str(out / "run.lcm")]
        player = subprocess.Popen(replay, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        while any(pinned in cpus for cpus in now.values()):
            assert time.monotonic() < deadline and watch.poll() is None, now
            time.sleep(0.1)
            now = threads_cpus(watch.pid)
        assert all(cpus == allowed - {pinned} for cpus in now.values()), now
        assert player.wait(timeout=60) == 0
    finally:
        for proc in (watch, player):
            if proc is not None:
                proc.kill()
                proc.communicate(timeout=30)


def test_a_real_runs_tables_tallied_as_heard_equal_skel_reports(tmp_path: Path) -> None:
    short_servo_run(tmp_path)
    run = load_run(tmp_path / "run.lcm")
    records = run.recorded.records
    tally, configs = RunTally(run.report.run_id), {run.config.generation: run.config}
    for end in range(0, len(records) + 1, max(1, len(records) // 7)):
        tally.update(dataclasses.replace(run.recorded, records=records[:end]), configs)
    tables = tally.update(run.recorded, configs)
    assert tables is not None and sum(p.cycles for p in tables.processes) > 1000
    _same_tables(tables, run.report)
    # Heard as a live view does, by a store that keeps only its newest 256 records: bounded,
    # and the tables still the whole run's.
    heard = Heard(keep_events=False)
    heard.listener.keep_records = 256
    events = read_log(tmp_path / "run.lcm").events
    most = 0
    for at in range(0, len(events), 40):
        for event in events[at : at + 40]:
            heard.handle(event.channel, event.data)
        heard.refresh()
        heard.find_faults()
        most = max(most, heard.store.n_held if heard.store else 0)
    assert heard.store is not None and heard.tables is not None
    assert heard.store.first > 0 and heard.store.unread == 0, (heard.store.first, heard.store.unread)
    assert most < 2 * 256, most
    _same_tables(heard.tables, run.report)
