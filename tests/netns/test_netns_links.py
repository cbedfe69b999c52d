"""Links that model a network the lab does not have, on namespace hosts (ttl=1): writers on two
hosts, their readers on a third, one run of three links, once with `run.network: emulated` (the
reading DPU emulates each link, dpu/buffers.c) and once with `kernel` (its host's tc and nft do
what they can, dpu/shape.c: here tbf and nftables; this kernel has no netem, so the DPU still
emulates latency). Either sits on a real network, and a writer on another host makes the delay
start at the arrival, so the real network adds to it.

- `radio`: a latency of 2 ms, measured against a plain link in the same run;
- `lossy`: 5 % lost, over 10,000 buffers;
- `can`: 1 Mbit/s offered twice that by two writers on two hosts: saturated, its queue full.

And what the kernel path applies is gone after the run, after `kill -9` of the host tool, and
after `kill -9` of the DPU that applied it (its guard undoes it).
"""

from __future__ import annotations

import re
import signal
from pathlib import Path
from typing import Any

import pytest

from netns import Hosts, hosts_fixture
from netns.test_netns_lab import URL, Lab, host_overrides, report_json, wait_until
from skeleton.host.cli.doctor import netem_present
from skeleton.host.sysfile.system import load

pytestmark = pytest.mark.timing  # judges the DPUs' timing: tests/steal.py

netns_four_hosts = hosts_fixture(4)

QUEUE_US, SLOW_US = 20_000, 5000
LINKS = f"""\
system: netns-links
links:
  - {{name: plain, url: "{URL}"}}
  - {{name: radio, url: "udpm://239.255.76.70:7677?ttl=1", latency_us: 2000}}
  - {{name: lossy, url: "udpm://239.255.76.73:7687?ttl=1", loss_pct: 5}}
  - {{name: can, url: "udpm://239.255.76.76:7697?ttl=1", bandwidth_mbps: 1, queue_us: {QUEUE_US}}}
dpus: [{{id: 1}}, {{id: 2}}, {{id: 3}}]
buffers:
  - {{id: 1, name: echo, bytes: 64, link: plain}}
  - {{id: 2, name: ping, bytes: 64, link: radio}}
  - {{id: 3, name: sample, bytes: 64, link: lossy}}
  - {{id: 4, name: scan, bytes: 1000, link: can}}
  - {{id: 5, name: pose, bytes: 200, link: can}}
processes:
  - {{id: 1, name: beacon, dpu: 1, period_us: 500, compute_us: 50, outputs: [echo, ping, sample]}}
  - {{id: 2, name: lidar, dpu: 1, period_us: {SLOW_US}, compute_us: 100, outputs: [scan]}}
  - {{id: 3, name: odometry, dpu: 2, period_us: {SLOW_US}, compute_us: 100, outputs: [pose]}}
  - {{id: 4, name: control, dpu: 3, period_us: 500, compute_us: 50, inputs: [echo, ping, sample]}}
  - {{id: 5, name: planner, dpu: 3, period_us: {SLOW_US}, compute_us: 100, inputs: [scan, pose]}}
run: {{duration_s: 5.5, warmup_cycles: 100, lockout_cycles: 50}}
"""


def _buffers(report: dict[str, Any]) -> dict[str, dict[str, Any]]:
    return {b["buffer"]: b for b in report["buffers"]}


def network_state(hosts: Hosts, host: str) -> str:
    """What a host's kernel shapes and filters: every qdisc, every link, the whole nft ruleset."""
    looks = (["tc", "qdisc", "show"], ["ip", "-o", "link", "show"], ["nft", "list", "ruleset"])
    return "\n".join(hosts.run(host, argv, capture_output=True, text=True, check=True).stdout
                     for argv in looks)


@pytest.mark.parametrize("network", ["kernel", "emulated"])
def test_netns_links_delay_lose_and_queue_as_modelled(netns_four_hosts: Hosts, tmp_path: Path,
                                                      network: str) -> None:
    lab = Lab(netns_four_hosts, tmp_path)
    h1, h2, h3, tool = netns_four_hosts.names
    for host, dpu in ((h1, "1"), (h2, "2"), (h3, "3")):
        lab.dpu(host, dpu)
    path = tmp_path / "links.yaml"
    path.write_text(LINKS)
    out = tmp_path / "run"
    before = network_state(netns_four_hosts, h3)
    done = lab.skel(tool, "run", str(path), "--url", URL, *host_overrides([h1, h2, h3]), "--out", str(out),
                    "-s", f"run.network={network}")
    assert done.returncode in (0, 3), done.stdout + done.stderr
    net = [line for line in done.stdout.splitlines() if line.startswith("NET DPU 3: ")]
    assert len(net) == 1, done.stdout
    if network == "kernel":  # each property's path, said; and nothing left on the host
        loss, latency = ("netem", "netem") if netem_present() else ("nft", "emulated")
        for said in ("link radio: latency " + latency, "link lossy: loss " + loss, "link can: bandwidth tbf"):
            assert said in net[0], net[0]
    else:
        assert "link can: bandwidth emulated" in net[0] and "run.network: emulated" in net[0], net[0]
    assert network_state(netns_four_hosts, h3) == before
    report = report_json(lab, tool, out / "run.lcm")
    buffers, links = _buffers(report), {k["link"]: k for k in report["links"]}

    # the radio's 2 ms on top of what the plain link took, each buffer's median
    added = buffers["ping"]["latency_us"]["p50"] - buffers["echo"]["latency_us"]["p50"]
    print(f"radio: +{added:.0f} us over the plain link's {buffers['echo']['latency_us']['p50']:.0f} us")
    assert 1800 <= added <= 2200, (buffers["ping"]["latency_us"], buffers["echo"]["latency_us"])

    # 5 % of 10,000 buffers lost on the way (the plain link, from the same writer, loses none)
    sample = buffers["sample"]
    assert sample["published"] >= 10_000, sample
    lost_pct = 100 * links["lossy"]["lost"] / sample["published"]
    print(f"lossy: {lost_pct:.2f} % of {sample['published']} lost")
    assert 3.5 <= lost_pct <= 6.5, links["lossy"]
    assert links["plain"]["lost"] == 0, links["plain"]

    # the bus: offered twice its bandwidth; its queue full, it drops what is over it
    system = load(path)
    bus, can = system.buses[system.link("can").id], links["can"]
    assert can["saturated"] and can["utilization_pct"] > 180, can
    print(f"can: {can['utilization_pct']:.0f} % used, {can['lost_bytes_pct']:.1f} % of its bytes lost "
          f"(modelled {bus.dropped_pct:.1f}; {can['lost_pct']:.1f} % of its messages), queue p99 "
          f"{can['queue_p99_us']:.0f} us")
    assert can["lost_bytes_pct"] == pytest.approx(bus.dropped_pct, abs=2.0), can
    # the scan alone needs more than the bus: whichever of the two comes second mostly finds the
    # queue full, so the pose may never get through; what does waits about the whole queue
    for name in ("scan", "pose") if buffers["pose"]["latency_us"]["p50"] is not None else ("scan",):
        wire = system.link("can").wire_us(system.buffer(name))
        p50 = buffers[name]["latency_us"]["p50"]
        # admitted within the queue, which a period's time runs down; the real network adds
        assert QUEUE_US - SLOW_US + wire <= p50 <= QUEUE_US + wire + 1000, (name, buffers[name]["latency_us"])
    lab.check_dpu_logs()


SHAPED = f"""\
system: netns-shaped
links:
  - {{name: can, url: "udpm://239.255.76.76:7697?ttl=1", bandwidth_mbps: 1, loss_pct: 1}}
dpus: [{{id: 1}}, {{id: 2}}, {{id: 3}}]
buffers:
  - {{id: 1, name: scan, bytes: 200, link: can}}
processes:
  - {{id: 1, name: lidar, dpu: 1, period_us: {SLOW_US}, compute_us: 100, outputs: [scan]}}
  - {{id: 2, name: planner, dpu: 2, period_us: {SLOW_US}, compute_us: 100, inputs: [scan]}}
  - {{id: 3, name: mapper, dpu: 3, period_us: {SLOW_US}, compute_us: 100, inputs: [scan]}}
run: {{duration_s: 8, warmup_cycles: 10, network: kernel}}
"""


def test_netns_kernel_network_is_undone_after_kill_9_of_the_host_tool_and_of_its_dpu(
        netns_four_hosts: Hosts, tmp_path: Path) -> None:
    """Both readers shape the link on their hosts. The host tool is killed: the DPU on h2 runs to the
    run's end and undoes it then; the DPU on h3 is killed too: its guard undoes it at once."""
    lab = Lab(netns_four_hosts, tmp_path)
    h1, h2, h3, tool = netns_four_hosts.names
    dpus = {host: lab.dpu(host, dpu) for host, dpu in ((h1, "1"), (h2, "2"), (h3, "3"))}
    before = {h: network_state(netns_four_hosts, h) for h in (h2, h3)}
    path = tmp_path / "shaped.yaml"
    path.write_text(SHAPED)
    skel = lab.skel_popen(tool, "run", str(path), "--url", URL, *host_overrides([h1, h2, h3]),
                          "--out", str(tmp_path / "run"))
    wait_until(lambda: re.search(r"run \d+ started", lab.dpu_logs[2].read_text()), 20,
               "the run never started on h3")
    for host in (h2, h3):  # applied, and `skel doctor` there says so
        state = network_state(netns_four_hosts, host)
        assert "tbf" in state and "ingress" in state and "numgen random" in state, state
        doctor = lab.skel(host, "doctor", "--url", URL)
        assert "applied now by a run's DPU" in doctor.stdout and "tbf" in doctor.stdout, doctor.stdout
    skel.send_signal(signal.SIGKILL)
    skel.wait()
    dpus[h3].send_signal(signal.SIGKILL)
    dpus[h3].wait()
    wait_until(lambda: network_state(netns_four_hosts, h3) == before[h3], 2,
               "h3 kept the killed DPU's tc or nft")
    assert network_state(netns_four_hosts, h2) != before[h2], "h2 undid it before its run's end"
    wait_until(lambda: re.search(r"run \d+ ended", lab.dpu_logs[1].read_text()), 15,
               "the run did not end on h2")
    wait_until(lambda: network_state(netns_four_hosts, h2) == before[h2], 2, "h2 kept the run's tc or nft")
    lab.check_dpu_logs()
