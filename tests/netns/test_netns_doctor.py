"""tests/unit/test_doctor.py's tests on network-namespace hosts (it says what they check)."""

from __future__ import annotations

import json
import re
import shlex
import sys

from unit.test_doctor import URL1

from netns import Hosts, hosts_fixture, require_command

netns_host = hosts_fixture(1)


# --- the whole doctor inside a host (root) --------------------------------------------------------
def _doctor_in(hosts: Hosts, url: str = URL1) -> tuple[int, str]:
    code = "import sys; from skeleton.host.cli.doctor import doctor; sys.exit(doctor(sys.argv[1]))"
    done = hosts.run("skelh1", [sys.executable, "-c", code, url], capture_output=True, text=True, timeout=30)
    return done.returncode, done.stdout


def _line(out: str, name: str) -> str:
    lines = [ln for ln in out.splitlines() if re.match(rf"(OK|WARN|FAIL) +{name} ", ln)]
    assert len(lines) == 1, out
    return lines[0]


def _apply_fix(hosts: Hosts, line: str) -> None:
    hosts.run("skelh1", shlex.split(line.split("fix: ", 1)[1]), check=True)


def test_netns_doctor_healthy_host_exits_0(netns_host: Hosts) -> None:
    code, out = _doctor_in(netns_host)
    assert code == 0, out
    assert "FAIL" not in out
    assert _line(out, "self-test").startswith("OK")
    assert _line(out, "record URL").startswith("OK  ") and "udpm://239.255.76.66:7666?ttl=1" in out, out


def test_netns_doctor_json(netns_host: Hosts) -> None:
    code = ("import sys; from skeleton.host.cli.doctor import doctor; "
            "sys.exit(doctor(sys.argv[1], as_json=True))")
    done = netns_host.run("skelh1", [sys.executable, "-c", code, URL1], capture_output=True, text=True)
    doc = json.loads(done.stdout)
    assert done.returncode == 0 and doc["ok"] is True
    assert {c["name"] for c in doc["checks"]} >= {"route", "interface", "rp_filter", "self-test"}


def test_netns_doctor_no_multicast_route(netns_host: Hosts) -> None:
    netns_host.run("skelh1", ["ip", "route", "del", "224.0.0.0/4"], check=True)
    code, out = _doctor_in(netns_host)
    assert code == 1
    line = _line(out, "route")
    assert line.startswith("FAIL") and "Network is unreachable" in line
    assert line.endswith("fix: ip route add 224.0.0.0/4 dev eth0")
    assert _line(out, "self-test").startswith("FAIL")
    _apply_fix(netns_host, line)
    assert _doctor_in(netns_host)[0] == 0


def test_netns_doctor_interface_without_multicast(netns_host: Hosts) -> None:
    netns_host.run("skelh1", ["ip", "link", "set", "eth0", "multicast", "off"], check=True)
    code, out = _doctor_in(netns_host)
    assert code == 1
    line = _line(out, "interface")
    assert line.startswith("FAIL") and line.endswith("fix: ip link set eth0 multicast on")
    _apply_fix(netns_host, line)
    assert _doctor_in(netns_host)[0] == 0


def test_netns_doctor_strict_rp_filter(netns_host: Hosts) -> None:
    netns_host.run("skelh1", ["sysctl", "-qw", "net.ipv4.conf.eth0.rp_filter=1"], check=True)
    code, out = _doctor_in(netns_host)
    line = _line(out, "rp_filter")
    assert line.startswith("WARN")
    assert line.endswith("fix: sysctl -w net.ipv4.conf.all.rp_filter=2 net.ipv4.conf.eth0.rp_filter=2")
    assert code == 0  # a risk for multi-homed hosts, not a failure here
    _apply_fix(netns_host, line)
    assert _line(_doctor_in(netns_host)[1], "rp_filter").startswith("OK")


def test_netns_doctor_firewall_drop_on_the_port(netns_host: Hosts) -> None:
    require_command("nft", "nftables")
    script = "table inet fw { chain input { type filter hook input priority 0; udp dport 7667 drop; }; }"
    netns_host.run("skelh1", ["nft", "-f", "-"], input=script, text=True, check=True)
    code, out = _doctor_in(netns_host)
    assert code == 1
    line = _line(out, "firewall")
    assert line.startswith("FAIL") and re.search(r"fix: nft delete rule inet fw input handle \d+$", line)
    assert _line(out, "self-test").startswith("FAIL")
    _apply_fix(netns_host, line)
    assert _doctor_in(netns_host)[0] == 0


def test_netns_doctor_firewall_drop_on_the_record_port(netns_host: Hosts) -> None:
    """The DPUs' heartbeats and timing go to the record URL's port, one below the control
    port: a firewall that drops it is found, and the record URL's own message fails."""
    require_command("nft", "nftables")
    script = "table inet fw { chain input { type filter hook input priority 0; udp dport 7666 drop; }; }"
    netns_host.run("skelh1", ["nft", "-f", "-"], input=script, text=True, check=True)
    code, out = _doctor_in(netns_host)
    assert code == 1
    failed = [ln for ln in out.splitlines() if re.match(r"FAIL +firewall ", ln)]
    assert len(failed) == 1 and "7666" in failed[0], out
    assert _line(out, "self-test").startswith("OK")  # the control URL itself is open
    assert _line(out, "record URL").startswith("FAIL")
    _apply_fix(netns_host, failed[0])
    assert _doctor_in(netns_host)[0] == 0
