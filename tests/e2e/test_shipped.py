"""What a user runs, run as a user runs it: the shipped daemon build/skel-dpu (the other tests
run the sanitizer build), the default URL and the default run folder (in a network namespace
of the test's own, so the default multicast group is private), `skel doctor` and `skel
allocate --objective latency` from the command line."""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

import pytest
from conftest import EXAMPLES, REPO, user_env

SKEL = REPO / ".venv" / "bin" / "skel"
SHIPPED = REPO / "build" / "skel-dpu"
PAIR = EXAMPLES / "pair-10ms-5ms.yaml"


def _in_own_netns(script: str, tmp_path: Path) -> subprocess.CompletedProcess[str]:
    """`script` in a new network namespace with a multicast route on its loopback only."""
    if os.geteuid() != 0 or shutil.which("unshare") is None or shutil.which("ip") is None:
        pytest.skip("a network namespace of its own needs root, unshare and ip (make test installs ip)")
    setup = "set -e; ip link set lo up; ip link set lo multicast on; ip route add 224.0.0.0/4 dev lo; "
    return subprocess.run(["unshare", "--net", "sh", "-c", setup + script], cwd=tmp_path,
                          env=user_env(tmp_path), capture_output=True, text=True, timeout=240)


@pytest.mark.timing   # the run's verdict is judged: a platform stall can lock a process out
def test_the_shipped_build_on_the_default_url_records_into_the_default_folder(tmp_path: Path) -> None:
    done = subprocess.run(["make", "--no-print-directory", "-s", "build/skel-dpu"], cwd=REPO,
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stdout + done.stderr
    script = (f"{SKEL} run {PAIR} --spawn -s run.cycles=200 -s run.warmup_cycles=10; "
              f"{SKEL} up {PAIR}; {SKEL} status --json --wait 3 > status.json; "
              "for pid in $(sed -n 's/.*\"pid\": \\([0-9]*\\).*/\\1/p' status.json); do "
              "readlink /proc/$pid/exe; done > exes.txt; "
              f"{SKEL} down; {SKEL} status --json --wait 1 > after.json")
    ran = _in_own_netns(script, tmp_path)
    assert ran.returncode == 0, ran.stdout + ran.stderr
    (run_dir,) = (tmp_path / "runs").iterdir()   # runs/<system>-<time>/, beside where skel ran
    assert run_dir.name.startswith("pair-10ms-5ms-"), run_dir
    report = json.loads((run_dir / "report.json").read_text())
    assert not report["fatal"] and len(report["dpus"]) == 2, report["faults"]
    status = json.loads((tmp_path / "status.json").read_text())
    assert sorted(d["dpu"] for d in status) == [1, 2], status
    exes = (tmp_path / "exes.txt").read_text().split()
    assert exes and set(exes) == {str(SHIPPED)}, exes
    assert json.loads((tmp_path / "after.json").read_text()) == []   # skel down stopped both


def test_skel_doctor_from_the_command_line_checks_this_machine(tmp_path: Path) -> None:
    done = subprocess.run([str(SKEL), "doctor"], env=user_env(tmp_path), capture_output=True, text=True,
                          timeout=60)
    lines = [line for line in done.stdout.splitlines() if line[:4] in ("OK  ", "WARN", "FAIL")]
    assert done.returncode == (1 if any(line.startswith("FAIL") for line in lines) else 0), done.stdout
    checks = {line.split()[1] for line in lines}
    assert {"url", "route", "self-test", "record"} <= checks, done.stdout


def test_skel_allocate_for_latency_writes_a_file_skel_check_accepts(tmp_path: Path) -> None:
    out = tmp_path / "servo-latency.yaml"
    done = subprocess.run([str(SKEL), "allocate", str(EXAMPLES / "servo.yaml"), "--objective", "latency",
                           "--time-limit", "20", "--out", str(out)], env=user_env(tmp_path),
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stdout + done.stderr
    assert "latency" in done.stdout, done.stdout
    checked = subprocess.run([str(SKEL), "check", str(out)], env=user_env(tmp_path), capture_output=True,
                             text=True, timeout=60)
    assert checked.returncode == 0, checked.stdout + checked.stderr
