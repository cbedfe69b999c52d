"""`skel doctor`: what on this machine stops LCM multicast, each problem with the command that fixes it.

Checks, in order: the URL itself, its ttl, the multicast route, the interface
that route leaves by (UP, MULTICAST), strict reverse-path filtering, socket
receive buffers, firewall rules that drop the port or multicast (best effort:
nftables, iptables), a real self-test: one LCM message published and
received on the URL within 1 s; then what a run's `run.network: kernel` can use
here (netem or not) and what a DPU's run applies now (dpu/shape.c). Reading only,
except the self-test's single datagram on the URL itself (ttl=0 keeps it on this host).
"""

from __future__ import annotations

import argparse
import gzip
import json
import os
import re
import secrets
import shutil
import subprocess
import sys
from collections.abc import Sequence
from dataclasses import asdict
from pathlib import Path
from typing import Literal, TextIO

from rich.text import Text

from skeleton.analysis.errors import EXIT_FAILED, EXIT_OK
from skeleton.analysis.views.console import OutputConsole
from skelmsg.contract import DEFAULT_URL, KEY_ENV

from ..live.preflight import Check
from ..sysfile.link import LcmUrl, parse_url, record_url, rmem_max, sysctl

MIN_RMEM_BYTES = 2 * 1024 * 1024
GOOD_RMEM_BYTES = 8 * 1024 * 1024
SELF_TEST_S = 1.0
SHAPE_PREFIX = "skl"  # dpu/shape.c: the ifb device and nft table of a link the kernel shapes


# --- small readers of the system's state ----------------------------------------------------
def _ip_json(*args: str) -> list[dict[str, object]] | None:
    """`ip -j ARGS`, or None when ip fails (e.g. "Network is unreachable")."""
    done = subprocess.run(["ip", "-j", *args], capture_output=True, text=True, timeout=10)
    if done.returncode != 0:
        return None
    return json.loads(done.stdout or "[]")


def _route_dev(group: str) -> str | None:
    routes = _ip_json("route", "get", group)
    return str(routes[0]["dev"]) if routes and "dev" in routes[0] else None


def _link(dev: str) -> dict[str, object] | None:
    links = _ip_json("link", "show", "dev", dev)
    return links[0] if links else None


def _suggested_iface(ttl: int) -> str:
    """Where multicast should go: lo for ttl=0, else the default route's or the first multicast link."""
    if ttl == 0:
        return "lo"
    default = _ip_json("route", "show", "default") or []
    candidates = [str(r["dev"]) for r in default if "dev" in r]
    candidates += [str(link["ifname"]) for link in _ip_json("link", "show") or []]
    for dev in candidates:
        link = _link(dev)
        flags = link.get("flags", []) if link else []
        if dev != "lo" and isinstance(flags, list) and "MULTICAST" in flags and "UP" in flags:
            return dev
    return "IFACE"


# --- checks -----------------------------------------------------------------------------
def check_ttl(url: LcmUrl) -> Check:
    if url.ttl == 0:
        return Check("ttl", False, "ttl=0 never leaves this host: fine on one machine, a multi-host lab "
                     "needs ttl=1", f"--url 'udpm://{url.group}:{url.port}?ttl=1'", "warn")
    return Check("ttl", True, f"ttl={url.ttl} reaches the local network")


def check_route(url: LcmUrl, dev: str | None, suggested: str) -> Check:
    if dev is None:
        # The interface check, next, says when that interface lacks MULTICAST (lo often does).
        return Check("route", False, f"no multicast route for {url.group}: LCM fails with "
                     '"Network is unreachable"', f"ip route add 224.0.0.0/4 dev {suggested}")
    if dev == "lo" and url.ttl > 0:
        return Check("route", False, f"{url.group} goes out lo: with ttl={url.ttl} other hosts never hear it",
                     f"ip route replace 224.0.0.0/4 dev {suggested}", "warn")
    return Check("route", True, f"{url.group} goes out {dev}")


def check_interface(dev: str, link: dict[str, object] | None) -> Check:
    if link is None:
        return Check("interface", False, f"no interface {dev}", "ip -br link  # pick one for the route")
    flags = link.get("flags", [])
    flags = flags if isinstance(flags, list) else []
    if "MULTICAST" not in flags:
        return Check("interface", False, f"{dev} lacks the MULTICAST flag: the kernel will not send or "
                     "join groups on it", f"ip link set {dev} multicast on")
    if "UP" not in flags:
        return Check("interface", False, f"{dev} is down", f"ip link set {dev} up")
    return Check("interface", True, f"{dev} is UP with MULTICAST")


def check_rp_filter(url: LcmUrl, dev: str, all_value: int | None, dev_value: int | None) -> Check:
    if url.ttl == 0 or dev == "lo":
        return Check("rp_filter", True, "only looped-back traffic, which reverse-path filtering skips")
    # The kernel applies the larger of conf.all and conf.<dev>.
    effective = max(all_value or 0, dev_value or 0)
    if effective == 1:
        return Check("rp_filter", False, f"strict reverse-path filtering on {dev} drops multicast from "
                     f"senders not routed back via {dev} (multi-homed hosts)",
                     f"sysctl -w net.ipv4.conf.all.rp_filter=2 net.ipv4.conf.{dev}.rp_filter=2", "warn")
    return Check("rp_filter", True, f"rp_filter={effective} on {dev}")


def check_socket_buffers(rmem_max: int | None, rmem_default: int | None,
                         recv_buf_size: int | None = None) -> Check:
    # LCM's sockets get rmem_default, or the URL's recv_buf_size capped at rmem_max.
    needed = max(MIN_RMEM_BYTES, recv_buf_size or 0)
    small = [f"net.core.{name}={value}" for name, value in (("rmem_max", rmem_max),
             ("rmem_default", rmem_default)) if value is not None and value < needed]
    good = max(GOOD_RMEM_BYTES, recv_buf_size or 0)
    if small:
        return Check("socket buffers", False, f"{', '.join(small)} (< {needed / 2**20:g} MiB): buffers above "
                     "~65 kB fragment and the kernel drops fragments that do not fit",
                     f"sysctl -w net.core.rmem_max={good} net.core.rmem_default={good}", "warn")
    return Check("socket buffers", True, f"rmem_max={rmem_max}, rmem_default={rmem_default}")


def _port_in(spec: str, port: int) -> bool:
    """nft `7667`, `{ 53, 7667 }`, `7000-8000`; iptables `7667`, `7000:8000`, `53,7667`."""
    for item in re.split(r"[\s,{}]+", spec):
        bounds = re.fullmatch(r"(\d+)[-:](\d+)", item)
        if (bounds and int(bounds[1]) <= port <= int(bounds[2])) or item == str(port):
            return True
    return False


def _drops_lcm(rule: str, url: LcmUrl, dport: re.Pattern[str]) -> Literal["fail", "warn"] | None:
    """Does a drop/reject rule hit LCM's datagrams? fail: certainly; warn: any UDP; None: no."""
    ports = dport.findall(rule)
    if "numgen random" in rule:  # loss injection: LCM works, minus a share of its datagrams
        return "warn" if _drops_lcm(rule.replace("numgen random", ""), url, dport) else None
    if ports:
        return "fail" if any(_port_in(p, url.port) for p in ports) else None
    if re.search(rf"224\.0\.0\.0/4|{re.escape(url.group)}\b|multicast", rule):
        return "fail"
    return "warn" if re.search(r"\budp\b", rule) else None


def firewall_findings_nft(ruleset: str, url: LcmUrl) -> list[Check]:
    """Rules in `nft -a list ruleset` that drop LCM's port or multicast, each with its delete command."""
    found: list[Check] = []
    table = chain = ""
    dport = re.compile(r"dport (\{[^}]*\}|\S+)")
    for line in ruleset.splitlines():
        line = line.strip()
        if m := re.match(r"table (\S+) (\S+) \{", line):
            table = f"{m[1]} {m[2]}"
        elif m := re.match(r"chain (\S+) \{", line):
            chain = m[1]
        elif m := re.search(r"hook (input|prerouting) .*policy drop", line):
            found.append(Check("firewall", False, f"nft {table} {chain}: {m[1]} policy drop: LCM passes "
                               f"only if a rule accepts udp dport {url.port}",
                               f"nft insert rule {table} {chain} udp dport {url.port} accept", "warn"))
        elif table.split(" ")[-1].startswith(SHAPE_PREFIX):
            continue  # a run's modelled loss (dpu/shape.c): the network check names it
        elif re.search(r"\b(drop|reject)\b", line) and (handle := re.search(r"# handle (\d+)", line)):
            severity = _drops_lcm(line, url, dport)
            if severity:
                rule = line.split(" # handle")[0]
                found.append(Check("firewall", False, f"nft {table} {chain}: `{rule}`",
                                   f"nft delete rule {table} {chain} handle {handle[1]}", severity))
    return found


def firewall_findings_iptables(saved: str, url: LcmUrl) -> list[Check]:
    """The same for `iptables-save` output."""
    found: list[Check] = []
    table = "filter"
    dport = re.compile(r"--dports? (\S+)")
    for line in saved.splitlines():
        if line.startswith("*"):
            table = line[1:].strip()
        elif m := re.match(r":(INPUT|PREROUTING) DROP", line):
            found.append(Check("firewall", False, f"iptables -t {table}: {m[1]} policy DROP: LCM passes only "
                               f"if a rule accepts udp dport {url.port}",
                               f"iptables -t {table} -I {m[1]} -p udp --dport {url.port} -j ACCEPT", "warn"))
        elif line.startswith("-A ") and re.search(r"-j (DROP|REJECT)\b", line):
            severity = _drops_lcm(line, url, dport)
            if severity:
                found.append(Check("firewall", False, f"iptables -t {table}: `{line}`",
                                   f"iptables -t {table} -D {line[3:]}", severity))
    return found


def check_firewall(url: LcmUrl) -> list[Check]:
    found: list[Check] = []
    looked = []
    if shutil.which("nft"):
        done = subprocess.run(["nft", "-a", "list", "ruleset"], capture_output=True, text=True, timeout=10)
        if done.returncode == 0:
            looked.append("nftables")
            found += firewall_findings_nft(done.stdout, url)
    if shutil.which("iptables-save"):
        done = subprocess.run(["iptables-save"], capture_output=True, text=True, timeout=10)
        if done.returncode == 0:
            looked.append("iptables")
            found += firewall_findings_iptables(done.stdout, url)
    if found:
        return found
    if not looked:
        return [Check("firewall", True, "no nft or iptables-save to read (or not root): not checked")]
    return [Check("firewall", True, f"no {' or '.join(looked)} rule drops udp port {url.port} or multicast")]


# Runs in a child so a C-level failure or hang of liblcm cannot take the doctor with it.
_SELF_TEST = """
import lcm, sys
url, channel, timeout_ms = sys.argv[1], sys.argv[2], int(sys.argv[3])
lc = lcm.LCM(url)
got = []
lc.subscribe(channel, lambda c, data: got.append(data))
lc.publish(channel, b"skel doctor")
while not got and lc.handle_timeout(timeout_ms) > 0:
    pass
sys.exit(0 if got else 3)
"""


def check_self_test(url: str, earlier_failed: bool) -> Check:
    channel = f"SKEL_DOCTOR_{os.getpid()}_{secrets.token_hex(3)}"
    argv = [sys.executable, "-c", _SELF_TEST, url, channel, str(int(SELF_TEST_S * 1000))]
    fix = "the FAIL lines above first" if earlier_failed else "see `ip route get`, `ip maddr`, the firewall"
    try:
        # +2 s for Python and liblcm to start; liblcm's own start-up self test blocks ~10 s when
        # its message does not come back, so a timeout here means the same as a missing message.
        done = subprocess.run(argv, capture_output=True, text=True, timeout=SELF_TEST_S + 2)
    except subprocess.TimeoutExpired:
        return Check("self-test", False, "published one message but did not receive it within 1 s", fix)
    if done.returncode == 0:
        return Check("self-test", True, "published and received one message within 1 s")
    if done.returncode == 3:
        return Check("self-test", False, "published one message but did not receive it within 1 s", fix)
    lines = [ln.strip() for ln in done.stderr.splitlines() if ln.strip()]
    why = next((ln for ln in lines if "unreachable" in ln.lower()), lines[-1] if lines else "no message")
    return Check("self-test", False, f"LCM could not start on the URL: {why}", fix)


def _route_checks(url: LcmUrl) -> list[Check]:
    """Route, the interface it leaves by, and that interface's reverse-path filter."""
    if shutil.which("ip") is None:
        return [Check("route", False, "no `ip` command: route and interface not checked",
                      "apt-get install iproute2", "warn")]
    dev = _route_dev(url.group)
    suggested = _suggested_iface(url.ttl) if dev is None or dev == "lo" else dev
    checks = [check_route(url, dev, suggested)]
    iface = dev or suggested
    if iface != "IFACE":
        checks.append(check_interface(iface, _link(iface)))
        checks.append(check_rp_filter(url, iface, sysctl("net/ipv4/conf/all/rp_filter"),
                                      sysctl(f"net/ipv4/conf/{iface}/rp_filter")))
    return checks


def netem_present() -> bool | None:
    """Whether this kernel has netem (built in or a module); None when it cannot be told."""
    release = os.uname().release
    if list(Path(f"/lib/modules/{release}/kernel/net/sched").glob("sch_netem.ko*")):
        return True
    try:
        with gzip.open("/proc/config.gz", "rt") as config:
            return any(line.startswith("CONFIG_NET_SCH_NETEM=") for line in config)
    except OSError:
        return None


def network_findings(netem: bool | None, shaped: dict[str, str], tables: list[str]) -> list[Check]:
    """What a run's `run.network: kernel` can use here, and what it has applied now: SHAPED is each
    skeleton ifb device -> its qdiscs, TABLES the skeleton nft tables."""
    if netem is False:
        can = ("no netem in this kernel: a link's bandwidth goes to tbf, its loss to nftables (without "
               "bursts), its latency and jitter are emulated by the DPUs")
    else:
        can = f"netem {'here' if netem else 'not known'}: a link's latency, jitter and loss go to netem, " \
              "its bandwidth to tbf"
    checks = [Check("network", True, can)]
    applied = [f"ifb {dev}: {q}" for dev, q in sorted(shaped.items())] + [f"nft table {t}" for t in tables]
    if applied:
        undo = "; ".join([f"ip link del {dev}" for dev in sorted(shaped)] +
                         [f"nft delete table inet {t}" for t in tables])
        checks.append(Check("network", False, f"applied now by a run's DPU (removed at its end): "
                            f"{'; '.join(applied)}", f"only when no run is going on: {undo}",
                            severity="warn"))
    return checks


def check_network() -> list[Check]:
    shaped: dict[str, str] = {}
    for link in _ip_json("link", "show", "type", "ifb") or []:
        dev = str(link.get("ifname", ""))
        if dev.startswith(SHAPE_PREFIX) and shutil.which("tc"):
            done = subprocess.run(["tc", "qdisc", "show", "dev", dev], capture_output=True, text=True,
                                  timeout=10)
            shaped[dev] = " | ".join(line.strip() for line in done.stdout.splitlines())
    tables: list[str] = []
    if shutil.which("nft"):
        done = subprocess.run(["nft", "list", "tables"], capture_output=True, text=True, timeout=10)
        tables = [w[-1] for w in (line.split() for line in done.stdout.splitlines())
                  if len(w) == 3 and w[-1].startswith(SHAPE_PREFIX)]
    return network_findings(netem_present(), shaped, tables)


def run_checks(url: str) -> list[Check]:
    try:
        parsed = parse_url(url)
    except ValueError as exc:
        return [Check("url", False, str(exc), f"--url '{DEFAULT_URL}'")]
    if parsed.provider != "udpm":
        checks = [Check("url", True, f"{parsed.provider}:// does not use the network")]
        return [*checks, check_self_test(url, False)]
    checks = [Check("url", True, f"group {parsed.group}, port {parsed.port}, ttl {parsed.ttl}"),
              check_ttl(parsed), *_route_checks(parsed),
              check_socket_buffers(rmem_max(), sysctl("net/core/rmem_default"),
                                   parsed.recv_buf_size),
              *check_firewall(parsed)]
    failed = any(not c.ok and c.severity == "fail" for c in checks)
    return [*checks, check_self_test(url, failed), *_record_checks(url, failed)]


def _record_checks(url: str, earlier_failed: bool) -> list[Check]:
    """The record URL (host/sysfile/link.py: record_url), where the DPUs send heartbeats, timing and
    reports: its port's firewall and a message of its own (its group, one below the control
    group, takes the same route in practice: one to 224.0.0.0/4 covers both)."""
    try:
        record = record_url(url)
    except ValueError as exc:
        return [Check("record URL", False, str(exc), f"--url '{DEFAULT_URL}'")]
    blocked = [c for c in check_firewall(parse_url(record)) if not c.ok]
    test = check_self_test(record, earlier_failed or any(c.severity == "fail" for c in blocked))
    said = f"{record} (heartbeats, timing, reports): {test.detail}"
    return [*blocked, Check("record URL", test.ok, said, test.fix, test.severity)]


STYLE = {"OK": "green", "WARN": "yellow", "FAIL": "bold red"}


def check_key(keyed: bool) -> Check:
    """Signed control: a warning (it works) when anyone on the group may command the DPUs."""
    if keyed:
        return Check("control", True, "signed: this host checks and signs control with its key")
    return Check("control", False, "unauthenticated (no key): anyone on this group can reconfigure, start, "
                 "stop or shut down the DPUs", f"skel keygen FILE, then --key FILE (or ${KEY_ENV}) for skel "
                 "and every skel-dpu", severity="warn")


def doctor(url: str, out: TextIO = sys.stdout, as_json: bool = False, keyed: bool = False) -> int:
    """Print one line per check (with the fix command for each problem); 0 when LCM works, 1 when not."""
    checks = [*run_checks(url), check_key(keyed), *check_network()]
    healthy = not any(not c.ok and c.severity == "fail" for c in checks)
    if as_json:
        doc = {"url": url, "ok": healthy, "checks": [{**asdict(c), "level": c.level} for c in checks]}
        out.write(json.dumps(doc, indent=2) + "\n")
        return EXIT_OK if healthy else EXIT_FAILED
    console = OutputConsole(file=out, highlight=False, soft_wrap=True)  # soft_wrap: one line per finding
    for check in checks:
        line = Text(f"{check.level:<5}", style=STYLE[check.level])
        line.append(f" {check.name:<15} {check.detail}")
        if not check.ok and check.fix:
            line.append(f"  fix: {check.fix}", style="bold")
        console.print(line)
    return EXIT_OK if healthy else EXIT_FAILED


def main(argv: Sequence[str] | None = None) -> int:
    """`python -m skeleton.host.cli.doctor [--url URL] [--json]` (the same as `skel doctor`)."""
    parser = argparse.ArgumentParser(prog="skel doctor", description="Check what stops LCM multicast here.")
    parser.add_argument("--url", default=DEFAULT_URL, help=f"LCM URL to check (default {DEFAULT_URL})")
    parser.add_argument("--json", action="store_true")
    args = parser.parse_args(argv)
    return doctor(args.url, as_json=args.json)


if __name__ == "__main__":
    sys.exit(main())
