"""End-to-end runs on one machine: real DPUs, real lcm-logger, real multicast (ttl=0)."""

from __future__ import annotations

import json
from pathlib import Path

from conftest import EXAMPLES, LOCKOUT_SYSTEM, skel

PAPER_COMPUTE_PCT = {1: 90.3, 2: 73.4, 3: 86.0, 4: 96.5}
# DPUs 1 and 3 are 86-90 % loaded: after a scheduling hiccup of a shared 2-core machine they
# catch up at only 10-14 % of real time. A lockout window of 20 periods (100 ms) keeps such
# noise from reading as a design flaw; the 2.5 ms system falls behind without bound either way.
NOISE_TOLERANT = ("-s", "run.lockout_cycles=20")


def _report(out: Path) -> dict:
    return json.loads((out / "report.json").read_text())


def test_servo_reproduces_table1_and_report_reproduces_run(tmp_path: Path, url: str) -> None:
    out = tmp_path / "servo"
    run = skel("run", str(EXAMPLES / "servo.yaml"), "--spawn", "--url", url, "--cycles", "800",
               "-s", "run.warmup_cycles=20", *NOISE_TOLERANT, "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    report = _report(out)
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2, 3, 4]
    for dpu in report["dpus"]:
        parts = dpu["compute_pct"] + dpu["communicate_pct"] + dpu["wait_pct"] + dpu["overhead_pct"]
        assert abs(parts - 100.0) < 1e-6, dpu
        assert abs(dpu["compute_pct"] - PAPER_COMPUTE_PCT[dpu["id"]]) <= 3.0, dpu
    assert not [f for f in report["faults"] if f["kind"] in ("lockout", "jam")], report["faults"]
    executor = next(p for p in report["processes"] if p["name"] == "executor")
    assert sorted(i["buffer_id"] for i in executor["inputs"]) == [3, 5, 6, 7, 8]

    # The log alone gives the same tables and the same JSON.
    again = skel("report", str(out / "run.lcm"))
    assert again.returncode == 0, again.stderr
    assert again.stdout.strip() and again.stdout.strip() in run.stdout
    as_json = skel("report", str(out / "run.lcm"), "--json")
    assert json.loads(as_json.stdout) == report


def test_servo_at_2_5ms_jams_and_locks_out(tmp_path: Path, url: str) -> None:
    out = tmp_path / "servo25"
    run = skel("run", str(EXAMPLES / "servo-2.5ms.yaml"), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode == 3, run.stdout + run.stderr
    faults = _report(out)["faults"]
    kinds = {f["kind"] for f in faults}
    assert "lockout" in kinds, faults
    assert "lockout" in run.stdout
    locked = {f["process"] for f in faults if f["kind"] == "lockout"}
    # DPU 4 keeps its 23.8 ms cycle and is not overloaded: none of its processes locks out.
    assert not locked & {"dynamics", "gravity_comp", "jacobian_update"}, faults


def test_mismatched_rates_give_stale_and_dropped(tmp_path: Path, url: str) -> None:
    out = tmp_path / "pair"
    run = skel("run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--spawn", "--url", url, "--duration", "3",
               "-s", "run.warmup_cycles=10", "--out", str(out))
    assert run.returncode == 0, run.stdout + run.stderr
    inputs = {(p["name"], i["buffer"]): i for p in _report(out)["processes"] for i in p["inputs"]}
    fast_reader = next(v for (proc, _), v in inputs.items() if proc == "fast_reader")
    slow_reader = next(v for (proc, _), v in inputs.items() if proc == "slow_reader")
    # A 10 ms writer read every 5 ms: new every other cycle, stale the others.
    stale_share = fast_reader["stale"] / (fast_reader["new"] + fast_reader["stale"])
    assert 0.4 <= stale_share <= 0.6, fast_reader
    assert fast_reader["dropped"] <= 0.02 * fast_reader["new"] + 2, fast_reader
    # A 5 ms writer read every 10 ms: every read is new and skips one sequence.
    assert slow_reader["stale"] <= 0.05 * slow_reader["new"] + 2, slow_reader
    assert 0.9 <= slow_reader["dropped"] / slow_reader["new"] <= 1.1, slow_reader




def test_lockout_of_a_data_synchronised_reader(tmp_path: Path, url: str) -> None:
    path = tmp_path / "lockout.yaml"
    path.write_text(LOCKOUT_SYSTEM)
    out = tmp_path / "run"
    run = skel("run", str(path), "--spawn", "--url", url, "--out", str(out))
    assert run.returncode == 3, run.stdout + run.stderr
    fault = next(f for f in _report(out)["faults"] if f["kind"] == "lockout")
    assert fault["process"] == "hungry_reader"
    assert fault["buffer"] == "slow_data"
    assert fault["writer"] == "slow_writer"
    # stop_on: lockout ends the run early instead of running the full 3 s.
    assert "stopping early" in run.stdout


def test_bad_system_file_is_one_line_exit_2(tmp_path: Path) -> None:
    path = tmp_path / "bad.yaml"
    path.write_text(LOCKOUT_SYSTEM.replace("period_us: 5000", "period_us: -5000"))
    for command in ("check", "run", "push"):
        result = skel(command, str(path))
        assert result.returncode == 2, (command, result.stdout, result.stderr)
        lines = result.stderr.strip().splitlines()
        assert len(lines) == 1 and "Traceback" not in result.stderr, result.stderr
        assert lines[0].startswith(f"{path}: processes.hungry_reader.period_us:"), lines[0]


def _executor_compute_us(out: Path) -> float:
    return next(p for p in _report(out)["processes"] if p["name"] == "executor")["compute_mean_us"]


def test_push_reconfigures_running_dpus_without_restart(tmp_path: Path, url: str, state_dir: Path) -> None:
    servo = str(EXAMPLES / "servo.yaml")
    assert skel("up", servo, "--url", url).returncode == 0
    try:
        pids_before = {d["dpu"]: d["pid"] for d in json.loads(skel("status", "--url", url, "--json").stdout)}
        assert sorted(pids_before) == [1, 2, 3, 4]
        first = skel("run", servo, "--url", url, "--cycles", "300", "-s", "run.warmup_cycles=10",
                     *NOISE_TOLERANT, "--out", str(tmp_path / "a"), "--compare-paper")
        assert first.returncode == 0, first.stdout + first.stderr
        assert "Table 1 beside this run" in first.stdout and "90.3" in first.stdout
        assert abs(_executor_compute_us(tmp_path / "a") - 3500) < 150

        pushed = skel("push", servo, "--url", url, "-s", "process.executor.compute_us=2000",
                      "-s", "run.warmup_cycles=10", *NOISE_TOLERANT)
        assert pushed.returncode == 0, pushed.stdout + pushed.stderr
        assert pushed.stdout.count("applied generation") == 4
        second = skel("run", "--url", url, "--cycles", "300", "--out", str(tmp_path / "b"))
        assert second.returncode == 0, second.stdout + second.stderr
        assert abs(_executor_compute_us(tmp_path / "b") - 2000) < 150

        pids_after = {d["dpu"]: d["pid"] for d in json.loads(skel("status", "--url", url, "--json").stdout)}
        assert pids_after == pids_before
    finally:
        assert skel("down", "--url", url).returncode == 0


def test_run_warns_when_a_process_would_stay_in_warm_up(tmp_path: Path, url: str) -> None:
    run = skel("run", str(EXAMPLES / "servo.yaml"), "--spawn", "--url", url, "--cycles", "100",
               "-s", "run.warmup_cycles=50", "-s", "run.lockout_cycles=40", "--out", str(tmp_path / "r"))
    assert run.returncode == 0, run.stdout + run.stderr
    # 50 cycles of 23.8 ms outlast a 0.5 s run: DPU 4's processes are never measured.
    for name in ("dynamics", "gravity_comp", "jacobian_update"):
        assert f"WARN process {name}: its warm-up" in run.stdout, run.stdout
    assert "WARN process executor" not in run.stdout
