"""Faults a lab survives, on namespace hosts (ttl=1): a DPU killed and restarted, packet loss,
the host tool killed, either start order. In each the run's data stays in the log and
`skel report` works on it.
"""

from __future__ import annotations

import json
import re
import signal
import subprocess
import time
from pathlib import Path
from typing import Any

import pytest
from conftest import EXAMPLES, Background

from netns import Hosts, hosts_fixture
from netns.test_netns_lab import URL, Lab, host_overrides, report_json, stop, wait_until
from skeleton.host.live.spawn import argv_of

netns_three_hosts = hosts_fixture(3)
netns_four_hosts = hosts_fixture(4)

# victim_writer's DPU is killed mid-run. free_reader reads its buffer every cycle (it goes
# stale and keeps running); synced_reader waits for it (data-synchronised: it locks out),
# alone on its DPU because a blocked process holds its whole cyclic executive.
KILL_SYSTEM = """\
system: netns-kill
dpus: [{id: 1}, {id: 2}, {id: 3}]
buffers: [{id: 1, name: victim, bytes: 64}]
processes:
  - {id: 1, name: victim_writer, dpu: 1, period_us: 10000, compute_us: 500, outputs: [victim]}
  - {id: 2, name: free_reader, dpu: 2, period_us: 10000, compute_us: 500, inputs: [victim]}
  - {id: 3, name: synced_reader, dpu: 3, period_us: 10000, compute_us: 500, sync: data, inputs: [victim]}
run: {duration_s: 4, warmup_cycles: 10, lockout_cycles: 20, stop_on: [jam]}
"""



def _system(tmp_path: Path, text: str, name: str = "system.yaml") -> str:
    path = tmp_path / name
    path.write_text(text)
    return str(path)


def _log_has(log: Path, pattern: str) -> bool:
    return bool(re.search(pattern, log.read_text(errors="replace")))


def _processes(report: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {p["name"]: p for p in report["processes"]}


def _input(report: dict[str, Any], process: str, buffer: str) -> dict[str, Any]:
    return next(i for i in _processes(report)[process]["inputs"] if i["buffer"] == buffer)


def test_netns_dpu_killed_is_lost_then_restarted_rejoins(netns_four_hosts: Hosts, tmp_path: Path) -> None:
    lab = Lab(netns_four_hosts, tmp_path)
    h1, h2, h3, tool = netns_four_hosts.names
    system = [_system(tmp_path, KILL_SYSTEM), "--url", URL, *host_overrides([h1, h2, h3])]
    victim = lab.dpu(h1, "1")
    lab.dpu(h2, "2")
    lab.dpu(h3, "3")
    out = tmp_path / "first"
    run = Background(lab.skel_popen(tool, "run", *system, "--out", str(out)))
    wait_until(lambda: _log_has(lab.dpu_logs[0], r"run \d+ started"), 15, "DPU 1 never started the run")
    time.sleep(1.0)
    victim.kill()
    killed = time.monotonic()
    victim.wait()
    wait_until(lambda: run.first(r"dpu_lost: DPU 1") is not None, 5, f"no dpu_lost:\n{run.output}")
    lost = run.first(r"dpu_lost: DPU 1")
    assert lost is not None
    lost_after_s = lost[0] - killed
    print(f"dpu_lost reported {lost_after_s * 1000:.0f} ms after SIGKILL")
    assert lost_after_s < 1.0, run.output

    # Restarted by host name while the run goes on: the run's periodic config re-send configures it.
    lab.dpu(h1, "auto")
    wait_until(lambda: _log_has(lab.dpu_logs[-1], r"applied generation"), 5,
               f"the restarted DPU never got the config:\n{lab.dpu_logs[-1].read_text()}")
    assert run.wait() == 3, run.output  # synced_reader's lockout is a fatal flaw
    assert "DPU 1 heard again" in run.output, run.output

    first = json.loads((out / "report.json").read_text())
    assert report_json(lab, tool, out / "run.lcm") == first  # the log alone gives the same
    faults = {(f["kind"], f.get("process"), f.get("dpu")) for f in first["faults"]}
    assert ("dpu_lost", None, 1) in faults, first["faults"]
    lockout = next(f for f in first["faults"] if f["kind"] == "lockout")
    assert (lockout["process"], lockout["buffer"], lockout["writer"]) == (
        "synced_reader", "victim", "victim_writer"), first["faults"]
    # DPU 2 ran all its cycles: 4 s of 10 ms, less the warm-up.
    assert _processes(first)["free_reader"]["cycles"] >= 385, _processes(first)["free_reader"]
    # Killed about 1 s into the 4 s run: most of free_reader's reads of `victim` are stale.
    stale_victim = _input(first, "free_reader", "victim")
    assert stale_victim["stale"] >= 200 and stale_victim["new"] >= 50, stale_victim

    # The next run, same file, no push: the restarted DPU is in it.
    second = tmp_path / "second"
    again = lab.skel(tool, "run", *system, "-s", "run.duration_s=1", "--out", str(second))
    assert again.returncode == 0, again.stdout + again.stderr
    report = json.loads((second / "report.json").read_text())
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2, 3]
    assert _input(report, "synced_reader", "victim")["new"] >= 80
    lab.check_dpu_logs()


# Loss model: every `victim` datagram into the lossy host is dropped with probability p, and
# nothing else drops a sequence when the reader sees exactly one new sequence per cycle. So
# the reader runs at its writer's rate, reads at the start of its period, and the writer
# publishes in the middle of it (compute 10 of 20 ms): 10 ms of scheduling noise either way
# before a phase slip could count as a drop. Then dropped / (new + dropped) = lost / sent ~ p.
# 16 buffers at 50 Hz for 2.5 s give ~1900 samples: the binomial sd is 0.5 %, so 5 % +- 2 is 4 sd.
LOSS_SYSTEM = """\
system: netns-loss
dpus: [{{id: 1}}, {{id: 2}}]
buffers:
{buffers}
processes:
  - {{id: 1, name: writer, dpu: 1, order: 2, period_us: 20000, compute_us: 10000, outputs: [{ahead}]}}
  - {{id: 2, name: reader, dpu: 2, order: 1, period_us: 20000, compute_us: 500, inputs: [{ahead}]}}
  - {{id: 3, name: echo, dpu: 2, order: 2, period_us: 20000, compute_us: 10000, outputs: [{back}]}}
  - {{id: 4, name: echo_reader, dpu: 1, order: 1, period_us: 20000, compute_us: 500, inputs: [{back}]}}
run: {{duration_s: 2.5, warmup_cycles: 10, lockout_cycles: 50, stop_on: [jam]}}
"""


def _loss_system() -> str:
    ahead = [f"a{i}" for i in range(16)]
    back = [f"e{i}" for i in range(4)]
    buffers = "\n".join(f"  - {{id: {i}, name: {name}, bytes: 64}}" for i, name in enumerate(ahead + back, 1))
    return LOSS_SYSTEM.format(buffers=buffers, ahead=", ".join(ahead), back=", ".join(back))


def _dropped_pct(inputs: list[dict[str, Any]]) -> float:
    dropped = sum(i["dropped"] for i in inputs)
    return 100 * dropped / (dropped + sum(i["new"] for i in inputs))


@pytest.mark.timing
def test_netns_five_percent_inbound_loss_shows_as_dropped(netns_three_hosts: Hosts, tmp_path: Path) -> None:
    lab = Lab(netns_three_hosts, tmp_path)
    h1, lossy, tool = netns_three_hosts.names
    lab.dpu(h1, "1")
    lab.dpu(lossy, "2")
    # Everything other hosts send to the lossy host is lost at 5 %: buffers (each writer's on a port
    # of its own), config, commands.
    netns_three_hosts.drop_inbound(lossy, 5)
    out = tmp_path / "loss"
    done = lab.skel(tool, "run", _system(tmp_path, _loss_system()), "--url", URL,
                    *host_overrides([h1, lossy]), "--out", str(out))
    assert done.returncode == 0, done.stdout + done.stderr
    report = report_json(lab, tool, out / "run.lcm")
    lossy_inputs = _processes(report)["reader"]["inputs"]
    clean_inputs = _processes(report)["echo_reader"]["inputs"]
    assert sum(i["new"] for i in lossy_inputs) >= 16 * 100, lossy_inputs
    loss, clean = _dropped_pct(lossy_inputs), _dropped_pct(clean_inputs)
    print(f"inbound loss 5 %: dropped {loss:.2f} % on the lossy host, {clean:.2f} % on the other")
    assert 3.0 <= loss <= 7.0, lossy_inputs
    assert clean <= 1.0, clean_inputs
    lab.check_dpu_logs()


def test_netns_host_tool_killed_dpus_and_logger_finish_the_run(netns_three_hosts: Hosts,
                                                               tmp_path: Path) -> None:
    lab = Lab(netns_three_hosts, tmp_path)
    h1, h2, tool = netns_three_hosts.names
    lab.dpu(h1, "1")
    lab.dpu(h2, "2")
    out = tmp_path / "killed"
    skel = lab.skel_popen(tool, "run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--url", URL,
                          *host_overrides([h1, h2]), "--duration", "3", "-s", "run.warmup_cycles=10",
                          "--out", str(out))
    wait_until(lambda: _log_has(lab.dpu_logs[0], r"run \d+ started"), 15, "the run never started")
    time.sleep(0.5)
    skel.send_signal(signal.SIGKILL)
    skel.wait()
    for log in lab.dpu_logs:
        wait_until(lambda log=log: _log_has(log, r"run \d+ ended"), 10, f"{log.name}: run did not end")
    time.sleep(0.5)  # the DPUs' last batches and reports, then the logger's 50 ms flush
    logger = [pid for pid in _pids(netns_three_hosts, tool) if b"lcm-logger" in b"\0".join(argv_of(pid))]
    assert logger, "the host tool's logger died with it"

    report = report_json(lab, tool, out / "run.lcm")
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2]
    assert not [f for f in report["faults"] if f["kind"] == "dpu_lost"], report["faults"]
    # 3 s: 600 cycles of the 5 ms processes, 300 of the 10 ms ones, each less its DPU's warm-up:
    # 10 cycles of the DPU's slowest process (10 ms), so 20 of the 5 ms ones.
    cycles = {name: p["cycles"] for name, p in _processes(report).items()}
    assert cycles["fast_writer"] >= 578 and cycles["fast_reader"] >= 578, cycles
    assert cycles["slow_writer"] >= 288 and cycles["slow_reader"] >= 288, cycles
    lab.check_dpu_logs()


def _pids(hosts: Hosts, host: str) -> list[int]:
    done = subprocess.run(["ip", "netns", "pids", hosts.netns(host)], capture_output=True, text=True,
                          check=True)
    return [int(p) for p in done.stdout.split()]


@pytest.mark.parametrize("order", ["dpus_first", "host_tool_first"])
def test_netns_start_order(netns_three_hosts: Hosts, tmp_path: Path, order: str) -> None:
    lab = Lab(netns_three_hosts, tmp_path)
    h1, h2, tool = netns_three_hosts.names
    out = tmp_path / order
    args = ("run", str(EXAMPLES / "pair-10ms-5ms.yaml"), "--url", URL, *host_overrides([h1, h2]),
            "--duration", "1", "-s", "run.warmup_cycles=10", "--wait-dpus", "15", "--out", str(out))
    if order == "dpus_first":
        daemons = [lab.dpu(h1), lab.dpu(h2)]
        time.sleep(0.5)
        done = lab.skel(tool, *args)
        code, output = done.returncode, done.stdout + done.stderr
    else:
        run = Background(lab.skel_popen(tool, *args))
        time.sleep(1.5)
        assert run.proc.poll() is None, run.output
        daemons = [lab.dpu(h1), lab.dpu(h2)]
        code, output = run.wait(), run.output
    assert code == 0, output
    report = json.loads((out / "report.json").read_text())
    assert sorted(d["id"] for d in report["dpus"]) == [1, 2]
    assert all(p["cycles"] >= 80 for p in report["processes"]), report["processes"]
    for proc in daemons:
        assert stop(proc) == 0
    lab.check_dpu_logs()
