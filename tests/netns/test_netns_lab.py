"""The SERVO example across hosts: four DPUs on four hosts, the host tool on a fifth, a logger on a sixth.

Also home of `Lab`, the small driver the other multi-host tests (test_netns_faults.py,
test_netns_scale.py) share: real skel-dpu daemons, the real `skel` and the real
lcm-logger, each started inside a namespace host, with ttl=1 links.
"""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path
from typing import Any

import lcm
import pytest
from conftest import ASAN_DPU, EXAMPLES, REPO, SANITIZER_ERROR, released_compute_pct

from netns import Hosts, hosts_fixture
from skeleton.host.live.spawn import LOGGED_CHANNELS
from skeleton.host.sysfile.link import record_url

pytestmark = pytest.mark.timing  # judges the DPUs' timing: tests/steal.py

GROUP = "239.255.76.67"
PORT = 7667  # inside the namespaces no other test shares it
URL = f"udpm://{GROUP}:{PORT}?ttl=1"
RELEASE_DPU = REPO / "build" / "skel-dpu"
# The wheel's real logger, not the venv's Python wrapper (a signal to the wrapper leaves it running).
LOGGER = Path(lcm.__file__).resolve().parent.parent / "bin" / "lcm-logger"

netns_six_hosts = hosts_fixture(6)


class Lab:
    """Starts daemons and commands in namespace hosts; keeps their logs under `root`."""

    def __init__(self, hosts: Hosts, root: Path) -> None:
        self.hosts = hosts
        self.root = root
        self.dpu_logs: list[Path] = []
        root.mkdir(parents=True, exist_ok=True)
        self.env = {**os.environ, "COLUMNS": "160", "PYTHONUNBUFFERED": "1",
                    "SKEL_STATE_DIR": str(root / "state")}

    def dpu(self, host: str, dpu_id: str = "auto", binary: Path = ASAN_DPU,
            extra: tuple[str, ...] = ()) -> subprocess.Popen[bytes]:
        assert binary.exists(), f"{binary} missing: run `make test` (it builds it)"
        log = self.root / f"dpu-{host}-{dpu_id}-{len(self.dpu_logs)}.log"
        self.dpu_logs.append(log)
        with open(log, "wb") as out:
            return self.hosts.popen(host, [str(binary), "--id", dpu_id, "--url", URL, *extra],
                                    stdout=out, stderr=subprocess.STDOUT, env=self.env)

    def skel(self, host: str, *args: str, timeout: float = 120) -> subprocess.CompletedProcess[str]:
        return self.hosts.run(host, [sys.executable, "-m", "skeleton.host.cli", *args], capture_output=True,
                              text=True, timeout=timeout, cwd=REPO, env=self.env)

    def skel_popen(self, host: str, *args: str) -> subprocess.Popen[str]:
        """`skel` in the background, its output line by line on .stdout (stderr merged)."""
        return self.hosts.popen(host, [sys.executable, "-m", "skeleton.host.cli", *args],
                                stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=REPO,
                                env=self.env)

    def logger(self, host: str, path: Path) -> subprocess.Popen[bytes]:
        """lcm-logger on `host` writing `path`; returns once the file is open."""
        with open(path.with_suffix(".logger.txt"), "wb") as out:
            # On the record URL, where a run's messages travel (host/sysfile/link.py), as the README says.
            argv = [str(LOGGER), "-f", "-q", "-l", record_url(URL), "-c", LOGGED_CHANNELS,
                    "--flush-interval=50", str(path)]
            proc = self.hosts.popen(host, argv, stdout=out, stderr=out)
        wait_until(path.exists, 5, f"lcm-logger on {host} did not open {path}")
        return proc

    def check_dpu_logs(self) -> None:
        for log in self.dpu_logs:
            text = log.read_text(errors="replace")
            assert not SANITIZER_ERROR.search(text.encode()), f"{log.name}: sanitizer report:\n{text}"


def wait_until(predicate: Any, timeout_s: float, what: str) -> None:
    deadline = time.monotonic() + timeout_s
    while not predicate():
        assert time.monotonic() < deadline, what
        time.sleep(0.05)


def stop(proc: subprocess.Popen[Any], timeout_s: float = 5) -> int:
    """SIGINT (the logger flushes and the DPU exits cleanly on it), then SIGKILL."""
    if proc.poll() is None:
        proc.send_signal(signal.SIGINT)
        try:
            proc.wait(timeout_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
    return proc.returncode


def host_overrides(hosts: list[str]) -> list[str]:
    """`-s dpu.N.host=NAME` putting DPU N on hosts[N-1]."""
    return [arg for i, host in enumerate(hosts, start=1) for arg in ("-s", f"dpu.{i}.host={host}")]


def report_json(lab: Lab, host: str, log: Path) -> dict[str, Any]:
    done = lab.skel(host, "report", str(log), "--json")
    assert done.returncode in (0, 3), done.stdout + done.stderr
    return json.loads(done.stdout)


def by_dpu(report: dict[str, Any]) -> dict[int, dict[str, Any]]:
    return {d["id"]: d for d in report["dpus"]}


def design_flaws(report: dict[str, Any]) -> list[dict[str, Any]]:
    """Lockouts, jams and lost DPUs: what a clean run must not have."""
    return [f for f in report["faults"] if f["kind"] in ("lockout", "jam", "dpu_lost")]


def clean_exit(done: subprocess.CompletedProcess[str], report: dict[str, Any]) -> None:
    """The run succeeded: no design flaw, exit 0."""
    assert not design_flaws(report), report["faults"]
    assert done.returncode == 0, done.stdout + done.stderr


def test_netns_servo_across_hosts_matches_one_machine(netns_six_hosts: Hosts, tmp_path: Path) -> None:
    lab = Lab(netns_six_hosts, tmp_path)
    *dpu_hosts, tool, logger_host = netns_six_hosts.names
    # 20 periods before a lockout: a loaded test machine's stalls are not a design flaw.
    cycles, lockout_cycles = 600, 20
    length = ["--cycles", str(cycles), "-s", "run.warmup_cycles=20", "-s",
              f"run.lockout_cycles={lockout_cycles}"]

    # The same file on one machine (a host of its own, ttl=0): the reference table.
    alone = tmp_path / "alone"
    done = lab.skel(logger_host, "run", str(EXAMPLES / "servo.yaml"), "--spawn", "--url",
                    f"udpm://{GROUP}:{PORT + 1}?ttl=0", *length, "--out", str(alone))
    assert (alone / "report.json").exists(), done.stdout + done.stderr
    one_machine = json.loads((alone / "report.json").read_text())
    clean_exit(done, one_machine)

    # The lab: DPUs find themselves by host name; nothing is pushed before `skel run`.
    daemons = [lab.dpu(host) for host in dpu_hosts]
    sixth = tmp_path / "sixth.lcm"
    logger = lab.logger(logger_host, sixth)
    out = tmp_path / "lab"
    done = lab.skel(tool, "run", str(EXAMPLES / "lab-servo.yaml"), "--url", URL, *host_overrides(dpu_hosts),
                    *length, "--out", str(out))
    time.sleep(0.3)  # the sixth host's logger flushes every 50 ms
    assert stop(logger) == 0
    assert (out / "report.json").exists(), done.stdout + done.stderr
    fifth = json.loads((out / "report.json").read_text())
    clean_exit(done, fifth)
    from_sixth = report_json(lab, logger_host, sixth)

    assert from_sixth["run_id"] == fifth["run_id"]
    assert sorted(by_dpu(from_sixth)) == [1, 2, 3, 4], from_sixth["dpus"]
    alone_by_dpu = by_dpu(one_machine)
    # % compute of what was released: each run's stalls are its own draw of the platform.
    for dpu_id, row in by_dpu(from_sixth).items():
        lab_pct = released_compute_pct(from_sixth, dpu_id)
        alone_pct = released_compute_pct(one_machine, dpu_id)
        print(f"DPU {dpu_id}: % compute of its releases {lab_pct:.1f} across hosts, {alone_pct:.1f} alone")
        assert abs(lab_pct - alone_pct) <= 3.0, (row, alone_by_dpu[dpu_id])
    # Two loggers on two hosts heard the same run: the same table, record for record.
    for key in ("dpus", "processes"):
        assert from_sixth[key] == fifth[key], key
    for report in (fifth, from_sixth):
        assert not report["integrity"]["lost_batches"], report["integrity"]
    for proc in daemons:
        assert stop(proc) == 0
    lab.check_dpu_logs()
