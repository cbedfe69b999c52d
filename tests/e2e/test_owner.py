"""A run belongs to the host tool that started it (real DPUs, real `skel`, ttl=0).

A second `skel run` or `skel push` of the same system on the same group, while a
run is in progress, is refused at once with the run, its host and its end, and
starts nothing; the DPUs refuse another session's config and commands on their
own; `--force` takes the run over and the DPUs log who did it.
"""

from __future__ import annotations

import json
import re
import socket
import time
from pathlib import Path

import pytest
from conftest import DpuFarm, faults_but_stalls, skel, skel_background

import skelmsg
from skeleton.host.live.control import Control
from skeleton.host.live.wire import config_message
from skeleton.host.sysfile.system import load, with_url

SYSTEM = """\
system: shared
dpus: [{id: 1}, {id: 2}]
buffers: [{id: 1, name: state, bytes: 64}]
processes:
  - {id: 1, name: sensor, dpu: 1, period_us: 10000, compute_us: 300, outputs: [state]}
  - {id: 2, name: controller, dpu: 2, period_us: 10000, compute_us: 300, inputs: [state]}
run: {warmup_cycles: 10, lockout_cycles: 100}
"""


def _system(tmp_path: Path) -> Path:
    path = tmp_path / "shared.yaml"
    path.write_text(SYSTEM)
    return path


def _running(url: str, ids: tuple[int, ...] = (1, 2), timeout_s: float = 20) -> dict[int, skelmsg.status_t]:
    """Wait until every DPU is running a run (a few cycles in); their heartbeats."""
    control = Control(url)
    try:
        assert control.wait_for(lambda: all(i in control.dpus and control.dpus[i].state == "running"
                                            and control.dpus[i].status.minor_cycles >= 20 for i in ids),
                                timeout_s), "the run did not start"
        return {i: v.status for i, v in control.snapshot().items()}
    finally:
        control.close()


@pytest.mark.timing  # the first run's faults are judged (faults_but_stalls): tests/steal.py
def test_second_run_and_push_are_refused_at_once_and_the_first_run_stays_clean(
        tmp_path: Path, url: str, dpus: DpuFarm, state_dir: Path) -> None:
    system = _system(tmp_path)
    dpus.start(1, 2)
    first_out = tmp_path / "first"
    first = skel_background("run", str(system), "--url", url, "--duration", "6", "--out", str(first_out))
    try:
        statuses = _running(url)
        run_id = statuses[1].run_id
        owner = f"{socket.gethostname()} pid {first.proc.pid}"
        assert statuses[1].run_owner == statuses[2].run_owner == owner
        assert statuses[1].run_end_utc_ns > time.time_ns()

        began = time.monotonic()
        second_out = tmp_path / "second"
        second = skel("run", str(system), "--url", url, "--duration", "2", "--out", str(second_out))
        second_s = time.monotonic() - began
        began = time.monotonic()
        push = skel("push", str(system), "--url", url, "-s", "process.sensor.compute_us=2000")
        push_s = time.monotonic() - began
        # With --spawn too: refused before its own DPUs are started.
        spawned_out = tmp_path / "spawned"
        spawned = skel("run", str(system), "--spawn", "--url", url, "--duration", "2",
                       "--out", str(spawned_out))
        code = first.wait(60)
    finally:
        if first.proc.poll() is None:
            first.proc.kill()
    for done, took in ((second, second_s), (push, push_s)):
        message = done.stdout + done.stderr
        assert done.returncode == 1, message
        # Names the run, its host tool, and when it ends; quickly (Python's start-up included).
        assert f"in run {run_id} of {socket.gethostname()} pid {first.proc.pid}" in message, message
        assert re.search(r"until \d\d:\d\d:\d\d UTC", message) and "--force" in message, message
        assert took < 5.0, (took, message)
    # The second run started nothing: no logger, no DPU of its own, no config staged anywhere.
    assert not (second_out / "run.lcm").exists()
    assert spawned.returncode == 1 and f"in run {run_id} of" in spawned.stdout, spawned.stdout
    assert not (spawned_out / "logs").exists() and not (spawned_out / "run.lcm").exists()
    assert "staged generation" not in dpus.log(1).split(f"run {run_id} armed")[1]
    assert code == 0, first.output
    # The run is over: nobody owns the DPUs any more, and their status no longer says so.
    status = skel("status", "--url", url, "--json", "--wait", "3")
    rows = {row["dpu"]: row for row in json.loads(status.stdout)}
    assert [(rows[i]["state"], rows[i]["run_owner"]) for i in (1, 2)] == [("ready", None)] * 2, rows
    report = json.loads((first_out / "report.json").read_text())
    assert len(report["generations"]) == 1, report["generations"]
    assert faults_but_stalls(report) == [], report["faults"]
    assert report["integrity"]["lost_batches"] == []


def test_dpus_refuse_another_sessions_config_and_stop_during_a_run(tmp_path: Path, url: str,
                                                                    dpus: DpuFarm) -> None:
    """The DPUs' own guard, whatever a host tool checks first: another session is refused."""
    system = with_url(load(_system(tmp_path)), url)
    dpus.start(1, 2)
    owner, intruder = Control(url), Control(url)
    try:
        owner.wait_heard([1, 2], 10)
        generation = owner.next_generation()
        assert owner.push(config_message(system, generation, 0, committed=False), [1, 2]).ok
        owner.start(generation, 42, time.time_ns() + 200_000_000, 3_000_000_000)
        assert owner.wait_for(lambda: all(owner.dpus[i].state == "running" for i in (1, 2)), 10)

        config = config_message(system, generation + 1, 42, committed=False)
        pushed = intruder.push(config, [1, 2], timeout_s=2)
        assert not pushed.committed and sorted(pushed.rejected) == [1, 2], pushed
        assert f"run 42 of {owner.sender} is in progress until" in pushed.rejected[1], pushed.rejected
        intruder.stop()
        time.sleep(0.5)
        views = owner.snapshot()
        assert all(views[i].state == "running" for i in (1, 2)), "another session's STOP stopped the run"
        assert "STOP from" in views[1].status.reject_reason and "refused" in views[1].status.reject_reason

        intruder.force = True  # --force: the STOP goes through, and the DPUs say whose it was
        intruder.stop()
        assert owner.wait_for(lambda: all(owner.dpus[i].state == "ready" for i in (1, 2)), 5)
    finally:
        owner.close()
        intruder.close()
    assert f"STOP from {intruder.sender} forced into run 42 of {owner.sender} (--force)" in dpus.log(1)
    assert "staged generation" not in dpus.log(2).split("run 42 armed")[1]


def test_force_takes_the_run_over(tmp_path: Path, url: str, dpus: DpuFarm) -> None:
    system = _system(tmp_path)
    dpus.start(1, 2)
    first = skel_background("run", str(system), "--url", url, "--duration", "30",
                            "--out", str(tmp_path / "a"))
    try:
        first_run = _running(url)[1].run_id
        second = skel("run", str(system), "--url", url, "--duration", "1", "--force", "--out",
                      str(tmp_path / "b"))
        first_code = first.wait(60)
    finally:
        if first.proc.poll() is None:
            first.proc.kill()
    assert second.returncode == 0, second.stdout + second.stderr
    assert f"--force: taking over: DPU 1, 2 are in run {first_run}" in second.stdout, second.stdout
    # The first host tool learns it at once, says who did it, and fails.
    assert first_code == 1, first.output
    assert re.search(rf"run {first_run} was (taken over by|stopped: STOP from) \S+ pid \d+", first.output), \
        first.output
    assert "INCOMPLETE" in first.output, first.output
    assert re.search(rf"STOP from \S+ pid \d+ forced into run {first_run} of", dpus.log(1)), dpus.log(1)
    report = json.loads((tmp_path / "b" / "report.json").read_text())
    assert faults_but_stalls(report) == [] and report["processes"][0]["cycles"] > 50
