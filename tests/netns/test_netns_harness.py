"""The multi-host harness itself: host names, unicast, LCM multicast across hosts, loss, clean-up."""

from __future__ import annotations

import re
import secrets
import subprocess
import sys

import pytest

from netns import Hosts, cleanup_stale, hosts_fixture, require_root
from netns.hosts import BRIDGE_NETFILTER, _netns_list

netns_hosts = hosts_fixture(3)

GROUP = "239.255.76.67"
PORT = 7667  # inside the namespaces no other test shares it

# Counts distinct sequence numbers until no message has come for `idle` seconds (or a deadline).
SUBSCRIBER = """
import lcm, select, sys, time
url, channel = sys.argv[1], sys.argv[2]
lc = lcm.LCM(url)
seen = set()
sub = lc.subscribe(channel, lambda c, data: seen.add(int(data)))
sub.set_queue_capacity(0)  # count what the network delivers, not what LCM's queue keeps
print("ready", flush=True)
deadline, last = time.monotonic() + float(sys.argv[3]), None
while time.monotonic() < deadline:
    if select.select([lc.fileno()], [], [], 0.2)[0]:
        lc.handle()
        last = time.monotonic()
    elif last is not None and time.monotonic() - last > 1.0:
        break
print(len(seen), flush=True)
"""

# Publishes N numbered messages, paced so no socket buffer along the way overflows.
PUBLISHER = """
import lcm, sys, time
lc = lcm.LCM(sys.argv[1])
for seq in range(int(sys.argv[3])):
    lc.publish(sys.argv[2], str(seq).encode())
    time.sleep(0.0003)
"""


def _root_links() -> set[str]:
    out = subprocess.run(["ip", "-o", "link"], capture_output=True, text=True, check=True).stdout
    return set(re.findall(r"^\d+: ([^:@]+)", out, re.MULTILINE))


def _send_and_count(hosts: Hosts, src: str, dst: str, url: str, count: int, deadline_s: float = 20) -> int:
    sub = hosts.popen(dst, [sys.executable, "-c", SUBSCRIBER, url, "NETNS_TEST", str(deadline_s)],
                      stdout=subprocess.PIPE, text=True)
    assert sub.stdout is not None
    assert sub.stdout.readline().strip() == "ready"
    hosts.run(src, [sys.executable, "-c", PUBLISHER, url, "NETNS_TEST", str(count)], check=True)
    out, _ = sub.communicate(timeout=deadline_s + 10)
    return int(out.split()[-1])


def test_netns_hosts_have_their_host_names(netns_hosts: Hosts) -> None:
    for name in netns_hosts.names:
        done = netns_hosts.run(name, ["hostname"], capture_output=True, text=True, check=True)
        assert done.stdout.strip() == name
        done = netns_hosts.run(name, [sys.executable, "-c", "import socket; print(socket.gethostname())"],
                               capture_output=True, text=True, check=True)
        assert done.stdout.strip() == name


def test_netns_hosts_reach_each_other(netns_hosts: Hosts) -> None:
    assert netns_hosts.ping("skelh1", "skelh2")
    assert netns_hosts.ping("skelh3", "skelh1")
    assert len({netns_hosts.address(h) for h in netns_hosts.names}) == 3


def test_netns_lcm_multicast_ttl1_crosses_hosts(netns_hosts: Hosts) -> None:
    url = f"udpm://{GROUP}:{PORT}?ttl=1"
    assert _send_and_count(netns_hosts, "skelh1", "skelh2", url, 200) == 200


def test_netns_lcm_multicast_ttl0_stays_on_its_host(netns_hosts: Hosts) -> None:
    url = f"udpm://{GROUP}:{PORT}?ttl=0"
    assert _send_and_count(netns_hosts, "skelh1", "skelh2", url, 20, deadline_s=2) == 0
    assert _send_and_count(netns_hosts, "skelh2", "skelh2", url, 20, deadline_s=5) == 20


def test_netns_drop_inbound_loses_about_the_asked_share(netns_hosts: Hosts) -> None:
    url = f"udpm://{GROUP}:{PORT}?ttl=1"
    netns_hosts.drop_inbound("skelh2", 5, udp_port=PORT)
    sent = 2000
    received = _send_and_count(netns_hosts, "skelh1", "skelh2", url, sent)
    loss_pct = 100 * (sent - received) / sent
    print(f"drop 5 %: measured {loss_pct:.2f} % over {sent} messages")
    assert 3 <= loss_pct <= 7
    netns_hosts.clear_drop("skelh2")
    assert _send_and_count(netns_hosts, "skelh1", "skelh2", url, 200) == 200


def test_netns_close_leaves_nothing_behind() -> None:
    require_root()
    links = _root_links()
    with Hosts(2) as hosts:
        ours = [hosts.bridge_netns, *(hosts.netns(h) for h in hosts.names)]
        assert set(ours) <= set(_netns_list())
        assert _root_links() == links, "the harness added a link to the root namespace"
        proc = hosts.popen("skelh1", ["sleep", "60"])
    assert proc.poll() is not None
    assert not set(ours) & set(_netns_list())
    assert _root_links() == links


def test_netns_bridge_forwards_without_the_firewall() -> None:
    """br_netfilter's sysctls are set to 0 in the bridge's namespace only: the root
    namespace's (the machine's own firewall) stay as they were."""
    require_root()
    if not BRIDGE_NETFILTER.exists():
        pytest.skip("br_netfilter is not loaded: a bridge here runs no firewall anyway")
    root = {f.name: f.read_text() for f in BRIDGE_NETFILTER.glob("bridge-nf-call-*")}
    with Hosts(1) as hosts:
        inside = subprocess.run(["ip", "netns", "exec", hosts.bridge_netns, "sh", "-c",
                                 f"cat {BRIDGE_NETFILTER}/bridge-nf-call-*"],
                                capture_output=True, text=True, check=True).stdout.split()
        assert inside and set(inside) == {"0"}
    assert {f.name: f.read_text() for f in BRIDGE_NETFILTER.glob("bridge-nf-call-*")} == root


def test_netns_cleanup_when_the_body_raises() -> None:
    require_root()
    links = _root_links()
    with pytest.raises(RuntimeError, match="boom"), Hosts(2) as hosts:
        ours = [hosts.bridge_netns, *(hosts.netns(h) for h in hosts.names)]
        proc = hosts.popen("skelh2", ["sleep", "60"])
        raise RuntimeError("boom")
    assert proc.poll() is not None
    assert not set(ours) & set(_netns_list())
    assert _root_links() == links


def test_netns_cleanup_stale_removes_a_crashed_runs_namespaces() -> None:
    require_root()
    # A prefix of its own: a parallel run's cleanup_stale() must not take the fake crashed run mid-build.
    prefix = f"skt{secrets.token_hex(2)}"
    dead = subprocess.Popen(["true"])
    dead.wait()
    crashed = Hosts(2, prefix, tag=f"{dead.pid}-dead")
    crashed.detach()  # as if its process had been killed before close()
    ours = [crashed.bridge_netns, *(crashed.netns(h) for h in crashed.names)]
    with Hosts(1, prefix) as alive:  # a live run's namespaces are never touched
        removed = cleanup_stale(prefix)
        assert set(ours) <= set(removed)
        assert alive.bridge_netns in _netns_list()
    assert not set(ours) & set(_netns_list())
