"""tests/unit/test_link.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

import os
import subprocess
from pathlib import Path

from conftest import DpuFarm, bound_udp_ports, skel, skel_background
from unit.test_link import _three

from skeleton.host.live import spawn
from skeleton.host.sysfile.link import parse_url, record_url
from skeleton.host.sysfile.system import loads, with_url


def test_check_and_the_dpu_refuse_a_control_url_without_a_record_url(tmp_path: Path) -> None:
    """Control on 224.0.0.0: its record group, one below, is not a multicast group."""
    path = _three(tmp_path, "udpm://224.0.0.0:7700?ttl=0")
    done = skel("check", str(path))
    assert done.returncode == 2, done.stdout + done.stderr
    assert done.stderr.strip() == (f"{path}: links.bus.url: 'udpm://224.0.0.0:7700?ttl=0': its record "
                                   "URL, group and port each 1 lower, would leave the multicast groups or "
                                   "the ports")
    dpu = subprocess.run([str(spawn.dpu_binary()), "--id", "1", "--url", "udpm://224.0.0.0:7700?ttl=0"],
                         capture_output=True, text=True, timeout=60)
    assert dpu.returncode == 1, dpu.stdout + dpu.stderr
    assert "--url udpm://224.0.0.0:7700?ttl=0: expected udpm://GROUP:PORT?options" in dpu.stderr, dpu.stderr


def _receive_threads(pid: int) -> list[tuple[int, int]]:
    """(policy, real-time priority) of each of the process's LCM link receive threads: they
    carry the name the control thread had when it started them (dpu/apply.c)."""
    found = []
    for task in Path(f"/proc/{pid}/task").iterdir():
        try:
            stat = (task / "stat").read_text()
        except OSError:
            continue  # ended meanwhile
        name, fields = stat[stat.index("(") + 1:stat.rindex(")")], stat[stat.rindex(")") + 2:].split()
        if name == "lcm-link":
            found.append((int(fields[38]), int(fields[37])))  # policy, rt_priority (proc(5))
    return found


def test_a_dpu_listens_only_on_the_ports_of_the_writers_it_reads(tmp_path: Path, url: str,
                                                                 dpus: DpuFarm) -> None:
    system_path = _three(tmp_path, url, duration=3.0)
    system = with_url(loads(system_path.read_text(), system_path), url)
    control = parse_url(url).port
    port = {name: parse_url(system.buffer_url(name)).port for name in ("a", "b")}
    assert port == {"a": control + 1, "b": control + 2}
    dpus.start(1, 2, 3)
    run = skel_background("run", str(system_path), "--url", url, "--out", str(tmp_path / "run"))
    run.wait_started(lambda: dpus.logs(1, 2, 3), 3)
    # (LCM's send sockets are bound too, to ephemeral ports: only the system's ports matter.)
    record = parse_url(record_url(url)).port
    assert record == control - 1
    ours = {control, record, *port.values()}
    bound = {d: bound_udp_ports(dpus.daemons[d].process.pid) & ours for d in (1, 2, 3)}
    receivers = {d: _receive_threads(dpus.daemons[d].process.pid) for d in (1, 2, 3)}
    assert run.wait(60) == 0, run.output
    # The reader of a, on DPU 3, has a socket on wa's port and none on wb's: the kernel hands it
    # none of b's datagrams. A writer's DPU sends to its port from an ephemeral one and is bound
    # to none of the system's but control: its own datagrams, looped back, wake nothing of it.
    assert bound[3] - {control} == {port["a"]}, bound
    assert bound[1] - {control} == set(), bound
    assert bound[2] - {control} == set(), bound
    assert all(control in ports for ports in bound.values()), bound
    # No DPU listens where the others send their heartbeats, timing and reports: the kernel
    # hands it none of them (only the host and the logger are bound to the record port).
    assert all(record not in ports for ports in bound.values()), bound
    # The reader's one receive thread runs under the executive's SCHED_FIFO priority (10 in
    # `sleep`, where permitted: these tests run as root), so the buffer a process waits on
    # does not queue behind ordinary threads; the writers' DPUs receive nothing, and have none.
    fifo = 10 if os.geteuid() == 0 else 0  # dpu.h SKEL_RT_PRIORITY
    assert receivers == {1: [], 2: [], 3: [(1, fifo) if fifo else (0, 0)]}, receivers
