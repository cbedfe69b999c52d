"""A run in a lab, on one machine (ttl=0, real daemons): DPUs lost, a host tool killed, start orders.

Each test drives the real `skel run` as a child process and interferes with it
the way a lab does: SIGKILL a DPU, SIGKILL the host tool's whole process group,
start the DPUs after the host tool.
"""

from __future__ import annotations

import json
import os
import re
import signal
import time
from pathlib import Path

import pytest
from conftest import DpuFarm, dpu_log_problems, skel, skel_background
from unit.test_host import _lab

from skeleton.analysis.read.messages import open_run_log
from skeleton.analysis.read.records import FLAG_SKIPPED, load_records
from skeleton.host.live import spawn
from skeleton.host.live.control import Control
from skelmsg.contract import DEFAULT_URL


def _wait_running(url: str, dpu: int, min_cycles: int = 50, timeout_s: float = 20) -> None:
    control = Control(url)
    try:
        assert control.wait_for(lambda: dpu in control.dpus and control.dpus[dpu].state == "running"
                                and control.dpus[dpu].status.minor_cycles >= min_cycles, timeout_s), \
            "the run did not start"
    finally:
        control.close()


def _report(out: Path) -> dict:
    done = skel("report", str(out / "run.lcm"), "--json")
    assert done.returncode in (0, 1, 3), done.stdout + done.stderr
    return json.loads(done.stdout)


def _inputs(report: dict) -> dict[str, dict]:
    return {p["name"]: i for p in report["processes"] for i in p["inputs"]}


def test_dpu_killed_mid_run_is_reported_and_the_others_are_analysed(dpus: DpuFarm, url: str,
                                                                      tmp_path: Path) -> None:
    dpus.start(1, 2)
    out = tmp_path / "run"
    run = skel_background("run", _lab(tmp_path), "--url", url, "--duration", "5", "--out", str(out))
    _wait_running(url, 1)
    killed = time.monotonic()
    dpus.kill(1)  # SIGKILL: no report, no last status
    deadline = time.monotonic() + 10
    while run.first("dpu_lost") is None and time.monotonic() < deadline:
        time.sleep(0.05)
    dpus.start(1)  # restarted: it takes the re-sent config, and sits out the rest of this run
    assert run.wait() == 1, run.output  # a DPU's part of the run is missing: "an operation failed"
    found = run.first(r"dpu_lost: DPU 1 not heard for ([0-9.]+) s")
    assert found is not None, run.output
    when, match = found
    # Detection is by heartbeat age (LOST_AFTER_S = 0.6 s, polled every 0.1 s): within 1 s of the last one.
    assert float(match.group(1)) <= 1.0, match.group(0)
    assert when - killed < 3.0, f"reported {when - killed:.2f} s after the kill"
    assert "dpu_lost: DPU 2" not in run.output

    report = json.loads((out / "report.json").read_text())
    assert report == _report(out)  # the log alone gives the same
    assert any(f["kind"] == "dpu_lost" and f.get("dpu") == 1 for f in report["faults"]), report["faults"]
    assert 2 in [d["id"] for d in report["dpus"]]
    # DPU 2 kept running to the end: its controller saw DPU 1's buffer go stale after the kill.
    controller = _inputs(report)["controller"]
    assert controller["stale"] > controller["new"], controller
    assert dpus.daemons[2].alive()
    assert "DPU 1 heard again" in run.output
    status = {d["dpu"]: d for d in json.loads(skel("status", "--url", url, "--json").stdout)}
    assert status[1]["generation"] == report["generation"], status


def test_dpu_killed_shortly_before_the_runs_end_is_in_the_report(dpus: DpuFarm, url: str,
                                                                   tmp_path: Path) -> None:
    """Killed 1.5 s before the end, a DPU was silent for less than the log's 2 s within the
    run: `skel run` said dpu_lost live and exited 1, while report.json had no fault (and its
    prediction blamed the platform for the missing data). It sent no report_t and was not
    heard after the run, while the other heartbeat on: lost."""
    dpus.start(1, 2)
    out = tmp_path / "run"
    run = skel_background("run", _lab(tmp_path), "--url", url, "--duration", "5", "--out", str(out))
    # 10 ms minor cycles: 350 of them is 3.5 s into the 5 s run, whatever the start took
    _wait_running(url, 1, min_cycles=350, timeout_s=30)
    dpus.kill(1)
    assert run.wait(90) == 1, run.output
    report = json.loads((out / "report.json").read_text())
    lost = [f for f in report["faults"] if f["kind"] == "dpu_lost"]
    assert [f["dpu"] for f in lost] == [1], report["faults"]
    assert "to its end and after, with no end-of-run report" in lost[0]["detail"], lost
    assert 3.0 < lost[0]["at_s"] < 4.9, lost  # its last heartbeat, before the kill
    assert report == _report(out)  # the log alone gives the same


def _logger_pids(log: Path) -> list[int]:
    """lcm-logger processes writing `log` (found by command line: the host tool that started them is dead)."""
    return [pid for pid, argv in spawn.running("lcm-logger").items() if str(log).encode() in argv]


def test_host_tool_killed_mid_run_dpus_finish_and_the_logger_keeps_recording(dpus: DpuFarm, url: str,
                                                                               tmp_path: Path) -> None:
    dpus.start(1, 2)
    out = tmp_path / "run"
    duration_s = 3.0
    run = skel_background("run", _lab(tmp_path), "--url", url, "--duration", str(duration_s),
                          "--out", str(out), new_session=True)
    _wait_running(url, 2, min_cycles=20)
    os.killpg(run.proc.pid, signal.SIGKILL)  # the whole process group, as a closed terminal would
    run.wait()
    assert _logger_pids(out / "run.lcm"), "the logger died with the host tool"
    # It ends by itself once the run is over (its `timeout`), having recorded the end of the run.
    deadline = time.monotonic() + duration_s + 30
    while _logger_pids(out / "run.lcm") and time.monotonic() < deadline:
        time.sleep(0.5)
    assert not _logger_pids(out / "run.lcm"), "the orphaned logger did not stop by itself"

    report = _report(out)
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2]
    assert not [f for f in report["faults"] if f["kind"] == "dpu_lost"], report["faults"]
    # Every cycle of the run is there: the controller runs every 10 ms for the whole duration.
    controller = next(p for p in report["processes"] if p["name"] == "controller")
    assert controller["cycles"] >= 0.9 * (duration_s / 0.010 - 10), controller
    assert all(d.alive() for d in dpus.daemons.values())


def test_dpus_started_before_and_after_the_host_tool(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    dpus.start(1)  # up before the host tool
    out = tmp_path / "run"
    run = skel_background("run", _lab(tmp_path), "--url", url, "--duration", "1", "--wait-dpus", "15",
                      "--out", str(out))
    time.sleep(2.0)
    assert run.proc.poll() is None, run.output  # still waiting for DPU 2
    dpus.start(2)  # up after it
    assert run.wait() == 0, run.output
    report = json.loads((out / "report.json").read_text())
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2]


def test_external_logger_prints_the_dpus_own_totals(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    dpus.start(1, 2)
    out = tmp_path / "run"
    done = skel("run", _lab(tmp_path), "--url", url, "--duration", "1", "--logger", "external",
                "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    assert "own totals" in done.stdout and "skel report" in done.stdout
    assert not (out / "run.lcm").exists()
    totals = json.loads((out / "reports.json").read_text())
    assert [row["dpu"] for row in totals["dpus"]] == [1, 2]
    assert all(row["reported"] and row["minor_cycles"] > 0 for row in totals["dpus"]), totals


def test_a_daemon_stuck_on_its_way_out_is_killed_not_orphaned(tmp_path_factory: pytest.TempPathFactory,
                                                               monkeypatch: pytest.MonkeyPatch) -> None:
    """`skel run --spawn` stops its DPUs with SIGINT; one that does not exit (here: it
    ignores the signal) is killed with the `timeout` wrapper around it, not left behind, and
    its log says so: what fails every DPU-starting test (conftest's _dpus_ended_clean), as a
    sanitizer's line does. (In a directory of its own: under tmp_path it would fail this test.)"""
    root = tmp_path_factory.mktemp("stuck")
    stuck = root / "stuck-dpu"
    pid_file = root / "pid"
    stuck.write_text(f"#!/bin/sh\ntrap '' INT TERM\necho 'dpu.c:1:2: runtime error: shift exponent 64'\n"
                     f"echo $$ > {pid_file}\nwhile :; do sleep 0.1; done\n")
    stuck.chmod(0o755)
    monkeypatch.setenv("SKEL_DPU", str(stuck))
    daemon = spawn.start_dpu(1, DEFAULT_URL, root, deadline_s=60)
    deadline = time.monotonic() + 5
    while not pid_file.exists() or not pid_file.read_text().strip():
        assert time.monotonic() < deadline, "the stand-in DPU did not start"
        time.sleep(0.05)
    pid = int(pid_file.read_text())
    assert spawn.stop(daemon, timeout_s=0.5) == -signal.SIGKILL
    deadline = time.monotonic() + 5
    while _alive(pid) and time.monotonic() < deadline:
        time.sleep(0.05)
    assert not _alive(pid), f"process {pid} outlived skel's stop"
    assert spawn.bad_exit(daemon) == "did not exit on SIGINT: killed"
    problems = dpu_log_problems(root)
    assert len(problems) == 2, problems
    assert "sanitizer report" in problems[0]
    assert "dpu 1 did not exit within 0.5 s of SIGINT: killed" in problems[1]


def _alive(pid: int) -> bool:
    """Running (a zombie nobody reaped yet is not running)."""
    try:
        state = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[0]
    except OSError:
        return False
    return state != "Z"


# A fan-in whose slow input is written once (at the run's start): after its first cycle the
# reader waits for data that never comes. Lockout rules relaxed, so the run goes on to its end.
STALLED_SYSTEM = """\
system: stalled
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: fast, bytes: 64}, {id: 2, name: once, bytes: 64}]
processes:
  - {id: 1, name: fast_writer, dpu: 1, period_us: 10000, compute_us: 300, outputs: [fast]}
  - {id: 2, name: once_writer, dpu: 1, period_us: 60000000, compute_us: 300, outputs: [once]}
  - {id: 3, name: fan_in, dpu: 2, period_us: 10000, compute_us: 300, sync: data, inputs: [fast, once]}
run: {warmup_cycles: 0, lockout_cycles: 1000000, stop_on: []}
"""


# DPU 2's next release is 20 s after its first: a switch waits for it.
SLOW_SYSTEM = """\
system: slow
dpus: [{id: 1}, {id: 2}]
processes:
  - {id: 1, name: fast_writer, dpu: 1, period_us: 10000, compute_us: 300}
  - {id: 2, name: rare, dpu: 2, period_us: 20000000, compute_us: 300}
run: {warmup_cycles: 0, stop_on: []}
"""


def _states(url: str, ids: list[int]) -> dict[int, str]:
    """Each DPU's state from its first heartbeat heard now (sent at once on every change)."""
    control = Control(url)
    try:
        assert control.wait_for(lambda: set(ids) <= control.dpus.keys(), 3.0), "a DPU is not heard"
        return {i: v.state for i, v in control.snapshot().items() if i in ids}
    finally:
        control.close()


def test_a_data_wait_whose_writer_stopped_ends_with_the_run(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    """The run's end ends the wait: the DPU that waits is not lost (it heartbeats), it
    reports on time and is READY when `skel run` returns, and the next run works."""
    system = tmp_path / "stalled.yaml"
    system.write_text(STALLED_SYSTEM)
    dpus.start(1, 2)
    out = tmp_path / "first"
    first = skel("run", str(system), "--url", url, "--duration", "2", "--out", str(out))
    states = _states(url, [1, 2])
    assert first.returncode == 0, first.stdout + first.stderr
    assert states == {1: "ready", 2: "ready"}, states
    assert "dpu_lost" not in first.stdout and "stopped it" not in first.stdout, first.stdout
    report = json.loads((out / "report.json").read_text())
    assert not [f for f in report["faults"] if f["kind"] == "dpu_lost"], report["faults"]
    # The wait itself ended at the run's end (its cycle is recorded, cut short), not later.
    records = load_records(open_run_log(out / "run.lcm"), report["run_id"]).records
    mine = records[records["process"] == 3]
    last = mine[mine["cycle"].argmax()]
    waited_until = int(last["start_ns"] + last["comm_in_ns"] + last["blocked_ns"])
    end = int(records["release_ns"].min()) + 2_000_000_000
    assert last["flags"] & FLAG_SKIPPED and waited_until - end < 100_000_000, (waited_until - end) / 1e6

    second = skel("run", str(system), "--url", url, "--duration", "1", "--out", str(tmp_path / "second"))
    assert second.returncode == 0, second.stdout + second.stderr


def test_a_push_says_what_each_dpu_did_with_it(dpus: DpuFarm, url: str, tmp_path: Path) -> None:
    system = tmp_path / "stalled.yaml"
    system.write_text(STALLED_SYSTEM)
    three = tmp_path / "three.yaml"  # DPU 3 is never started
    three.write_text(STALLED_SYSTEM.replace("[{id: 1}, {id: 2}]", "[{id: 1}, {id: 2}, {id: 3}]").replace(
        "processes:\n", "processes:\n  - {id: 4, name: idle, dpu: 3, period_us: 10000, compute_us: 100}\n"))
    dpus.start(1, 2)
    ok = skel("push", str(system), "--url", url)
    assert ok.returncode == 0, ok.stdout + ok.stderr
    generation = int(re.search(r"DPU 1: applied generation (\d+)", ok.stdout).group(1))

    # Not committed: DPU 1 staged it, DPU 2 refused it, DPU 3 never answered; each is named.
    bad = skel("push", str(three), "--url", url, "-s", "dpu.2.cpu=1000")
    assert bad.returncode == 1, bad.stdout + bad.stderr
    g = generation + 1
    assert f"DPU 1: staged generation {g}, not applied: it keeps generation {generation}" in bad.stderr
    assert f"DPU 2: rejected generation {g}: " in bad.stderr
    assert "DPU 2: cpu 1000 is not one this host lets it run on" in bad.stderr, bad.stderr
    assert f"DPU 3: did not answer generation {g}" in bad.stderr
    assert "nothing was committed" in bad.stderr

    # Committed, but DPU 2 cannot switch in time: its next release (where it would) is 20 s
    # away, past the common grid's 10 s cap (a DPU waiting inside a data wait is the same
    # case, but cycle skipping lets it catch up once its data comes). DPU 1 applied it, DPU 2
    # did not, and the push says both. The run is this test's own Control's, another
    # session: a push into it needs --force.
    slow = tmp_path / "slow.yaml"
    slow.write_text(SLOW_SYSTEM)
    base = skel("push", str(slow), "--url", url)
    assert base.returncode == 0, base.stdout + base.stderr
    generation = int(re.search(r"DPU 1: applied generation (\d+)", base.stdout).group(1))
    control = Control(url)
    try:
        control.start(generation, 77, time.time_ns() + 300_000_000, 0)  # until STOP
        _wait_running(url, 2, min_cycles=1)
        partial = skel("push", str(slow), "--url", url, "-s", "process.fast_writer.compute_us=400", "--force")
    finally:
        control.stop()
        control.close()
    assert partial.returncode == 1, partial.stdout + partial.stderr
    g = generation + 1
    assert f"DPU 1: applied generation {g}" in partial.stdout, partial.stdout + partial.stderr
    assert (f"DPU 2: staged generation {g} but did not apply it: it still applies generation "
            f"{generation} (running)") in partial.stderr, partial.stderr
    assert f"generation {g} was committed: applied by DPU 1; not by DPU 2" in partial.stderr
    assert "nothing was committed" not in partial.stderr
