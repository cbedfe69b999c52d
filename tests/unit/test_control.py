"""control.py against what anyone on the group may send: stray configs, heartbeats, reports and
ping answers (published for real with the lcm module on the test's private URL) never crash the
host tool nor choose its numbers, and real DPUs are pushed to and run afterwards."""

from __future__ import annotations

import os
import re
import socket
import subprocess
import time

import lcm
import pytest
from conftest import EXAMPLES, skel

import skelmsg
from skeleton.analysis.errors import EXIT_FAILED
from skeleton.host.live.control import Control
from skeleton.host.live.listener import REPORTS_KEPT
from skeleton.host.live.repair import SeenBatches
from skeleton.host.live.wire import config_message
from skeleton.host.sysfile.link import RECORD_RECV_BYTES, parse_url, record_listen_url, record_url, rmem_max
from skeleton.host.sysfile.system import load, with_url
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL

INT64_MAX = 2**63 - 1
PAIR = EXAMPLES / "pair-10ms-5ms.yaml"


def _publish(url: str, channel: str, *messages: object, repeats: int = 3) -> None:
    """As another host tool (or DPU) would: on the control URL and its record URL."""
    buses = [lcm.LCM(url), lcm.LCM(record_url(url))]
    for _ in range(repeats):  # multicast may lose one
        for message in messages:
            for bus in buses:
                bus.publish(channel, message.encode())  # type: ignore[attr-defined]
        time.sleep(0.05)


def _stray_config(url: str, generation: int, committed: bool, valid: bool) -> skelmsg.config_t:
    """A well-formed config of the test's own system: every DPU refuses it unless `valid`."""
    config = config_message(with_url(load(PAIR), url), generation, 0, committed=committed)
    if not valid:
        for process in config.processes:
            process.compute_us = -1
    return config


def _heartbeat(dpu: int, **fields: int) -> skelmsg.status_t:
    status = skelmsg.status_t()
    status.dpu, status.host, status.pid, status.state = dpu, "stray", 4242, skelmsg.status_t.STATE_RUNNING
    status.reject_reason = ""
    status.nlockouts, status.lockouts = 0, []
    for name, value in fields.items():
        setattr(status, name, value)
    return status


def test_stray_heartbeats_reports_and_configs_are_bounded(url: str) -> None:
    control = Control(url)
    try:
        huge = {"generation": INT64_MAX, "staged_generation": INT64_MAX, "rejected_generation": INT64_MAX,
                "run_id": INT64_MAX}
        _publish(url, STATUS_CHANNEL, _heartbeat(7, **huge), _heartbeat(0), _heartbeat(-9),
                 _heartbeat(-1, pid=1))
        assert control.wait_for(lambda: 7 in control.dpus and -1 in control.dpus, 3.0)
        # Neither a stray DPU's generations nor its run choose our numbers.
        assert control.next_generation() == 1
        assert 0 not in control.dpus and -9 not in control.dpus
        assert control.foreign_generations([7]) == {7: INT64_MAX}
        # A flood of reports of made-up runs cannot grow without bound; nonsense ones are refused.
        flood = []
        for run_id in range(1, REPORTS_KEPT + 50):
            report = skelmsg.report_t()
            report.dpu, report.run_id, report.nprocesses, report.processes = 3, run_id, 0, []
            flood.append(report)
        bad = skelmsg.report_t()
        bad.dpu, bad.run_id, bad.nprocesses, bad.processes = 3, -1, 0, []
        for i in range(0, len(flood), 50):  # in slices the socket buffer holds
            _publish(url, REPORT_CHANNEL, *flood[i:i + 50], repeats=1)
        _publish(url, REPORT_CHANNEL, flood[-1], bad)
        assert control.wait_for(lambda: (3, REPORTS_KEPT + 49) in control.reports, 5.0)
        assert len(control.reports) <= REPORTS_KEPT
        # Generations no host tool makes are not kept as configs to re-send.
        for generation in (-5, INT64_MAX):
            stray = _stray_config(url, generation, committed=True, valid=True)
            _publish(url, CONFIG_CHANNEL, stray, repeats=1)
        time.sleep(0.3)
        assert not control.configs
        assert control.rejected_messages >= 4  # DPU ids 0 and -9, the bad report, the configs
    finally:
        control.close()


def test_ping_answers_must_echo_our_ping_and_fit_a_clock_offset(url: str) -> None:
    control = Control(url)
    try:
        seq = control.ping()
        t1 = control._ping_t1[seq]
        fakes = [
            _heartbeat(5, ping_seq=seq, ping_t1_ns=t1 + 1, ping_t2_ns=t1, ping_t3_ns=t1),  # not our t1
            _heartbeat(6, ping_seq=seq, ping_t1_ns=t1, ping_t2_ns=-(2**63), ping_t3_ns=-(2**63)),  # overflow
            _heartbeat(8, ping_seq=seq, ping_t1_ns=t1, ping_t2_ns=t1 + 9, ping_t3_ns=t1 + 1),  # t3 < t2
            _heartbeat(9, ping_seq=seq, ping_t1_ns=t1, ping_t2_ns=t1 + 1, ping_t3_ns=t1 + 2),  # plausible
        ]
        _publish(url, STATUS_CHANNEL, *fakes, repeats=1)
        assert control.wait_pongs([seq], [9], 3.0)
        assert set(control.pongs([seq])) == {9}
    finally:
        control.close()


def test_the_log_repair_ignores_a_stray_batch_number() -> None:
    seen = SeenBatches()
    for seq in (0, 1, 2, 4, 2**62, -3):
        seen.add(seq)
    # Counting the holes up to 2**62 would never end: the stray number is not one of the DPU's.
    assert seen.missing(None) == [3]
    assert seen.missing(INT64_MAX) == [3]
    assert seen.missing(8) == [3, 5, 6, 7]


@pytest.mark.parametrize("command", [("watch", "--duration", "1"), ("status",)])
def test_a_taken_port_is_said_in_one_line(command: tuple[str, ...]) -> None:
    """Another program holds the UDP port the host hears on (the record URL's: the control
    URL's less one) without sharing it: LCM cannot bind, and the command says so in one line
    (it raised AttributeError from a None subscription)."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as holder:
        holder.bind(("0.0.0.0", 0))
        port = holder.getsockname()[1]
        done = skel(*command, "--url", f"udpm://239.255.76.67:{port + 1}?ttl=0")
    assert done.returncode == EXIT_FAILED, done.stdout + done.stderr
    said = [line for line in done.stderr.splitlines() if line.startswith("skel:")]
    assert said == [f"skel: cannot receive on udpm://239.255.76.66:{port}?ttl=0: its port is taken by "
                    "another program"], done.stderr
    assert "Traceback" not in done.stderr


def test_the_host_asks_for_a_large_socket_buffer_on_the_record_url(url: str) -> None:
    """Every DPU's timing batch comes after the same releases: the host's socket on the record
    URL asks for RECORD_RECV_BYTES (capped at net.core.rmem_max), which the kernel doubles."""
    limit = rmem_max()
    control = Control(url)
    try:
        port = parse_url(control.record_url).port
        done = subprocess.run(["ss", "-uanpm", f"sport = :{port}"], capture_output=True, text=True,
                              check=True)
    finally:
        control.close()
    mine = done.stdout.split(f"pid={os.getpid()},")[1]
    (granted,) = re.findall(r"rb(\d+)", mine)[:1]
    assert limit is not None and int(granted) == 2 * min(RECORD_RECV_BYTES, limit), done.stdout
    assert record_listen_url(url, None) == record_url(url)  # rmem_max unknown: LCM's default
    assert record_listen_url(url + "&recv_buf_size=4096", limit) == record_url(url + "&recv_buf_size=4096")
