"""Several "hosts" on one machine: network namespaces joined by a bridge, for multi-host tests.

Each host is a network namespace with one veth link (`eth0`, MULTICAST on, an
address on 10.213.77.0/24, a multicast route `224.0.0.0/4 dev eth0`) and its own
host name: every process started in it gets a private UTS namespace whose host
name is the host's (`skelh1`, `skelh2`, ...), so `skel-dpu --id auto` works.
The other veth ends sit in one more namespace that holds the bridge. Nothing
is added to the root namespace: the veth pairs are created inside the bridge
namespace, so no link, address or route ever appears there, and traffic never
leaves these namespaces. Like a lab switch, the bridge runs no firewall on the frames it
forwards (see _no_bridge_firewall).

Namespaces are named `<prefix>-<pid>-<rand>-br` / `-h<i>`: parallel runs never
collide, and `cleanup_stale()` removes those whose owning process is gone.

From Python:

    with Hosts(3) as hosts:
        dpu = hosts.popen("skelh1", ["build/skel-dpu", "--id", "auto", "--url", url])
        hosts.drop_inbound("skelh2", 5, udp_port=7667)

From a shell (as root), for trying things by hand:

    .venv/bin/python -m tests.netns.hosts up 3           # leaves namespaces skel-cli-*
    .venv/bin/python -m tests.netns.hosts exec skelh1 hostname
    .venv/bin/python -m tests.netns.hosts exec skelh2 .venv/bin/skel status --url 'udpm://239.255.76.67:7667?ttl=1'
    .venv/bin/python -m tests.netns.hosts down           # removes skel-cli-* and any stale run's
"""

from __future__ import annotations

import argparse
import atexit
import os
import re
import secrets
import shutil
import signal
import subprocess
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

SUBNET = "10.213.77"  # a /24 that exists only inside these namespaces
BRIDGE = "br0"
HOST_IF = "eth0"
NFT_TABLE = "skel_harness"
CLI_TAG = "cli"  # `up` from the command line: owned by no live process, removed by `down`
NETNS_DIR = Path("/run/netns")


class HarnessError(RuntimeError):
    """A namespace, link or rule could not be set up; the message has the failing command."""


def _ip(*args: str) -> None:
    _check(["ip", *args])


def _check(argv: list[str], stdin: str | None = None) -> str:
    done = subprocess.run(argv, input=stdin, capture_output=True, text=True, timeout=30)
    if done.returncode != 0:
        raise HarnessError(f"`{' '.join(argv)}` failed ({done.returncode}): {done.stderr.strip()}")
    return done.stdout


def _wrap(netns: str, host: str, argv: Sequence[str]) -> list[str]:
    # A private UTS namespace per process, all named after the host: no holder process to keep alive.
    return ["nsenter", f"--net={NETNS_DIR / netns}", "--", "unshare", "--uts", "--",
            "sh", "-c", 'hostname "$0" && exec "$@"', host, *argv]


BRIDGE_NETFILTER = Path("/proc/sys/net/bridge")  # there only while br_netfilter is loaded


def _no_bridge_firewall(netns: str) -> None:
    """A lab switch forwards frames without looking at them. Where br_netfilter is loaded
    (container runtimes load it), a new namespace's bridge would pass every frame through that
    namespace's iptables (its sysctls default to 1): at 96 DPUs 49-77 % of the buffers were
    dropped with that work, 14-27 % without (`make bench` part scale). The sysctls are the
    namespace's own."""
    if BRIDGE_NETFILTER.exists():  # per namespace since Linux 5.3; before, absent inside it
        script = f"set -e; for f in {BRIDGE_NETFILTER}/bridge-nf-call-*; do [ ! -e $f ] || echo 0 > $f; done"
        _check(["ip", "netns", "exec", netns, "sh", "-c", script])


def _netns_list() -> list[str]:
    # /run/netns is what `ip netns list` reads; listing it directly needs no subprocess.
    if not NETNS_DIR.is_dir():
        return []
    return sorted(p.name for p in NETNS_DIR.iterdir())


def _kill_netns_processes(netns: str) -> None:
    """SIGKILL everything inside a namespace: a namespace with processes in it outlives `ip netns del`."""
    for _ in range(50):
        done = subprocess.run(["ip", "netns", "pids", netns], capture_output=True, text=True, timeout=10)
        pids = [int(p) for p in done.stdout.split()] if done.returncode == 0 else []
        if not pids:
            return
        for pid in pids:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
        time.sleep(0.02)


def _delete_netns(netns: str) -> None:
    _kill_netns_processes(netns)
    # Deleting a host namespace destroys its veth end, and with it the peer on the bridge.
    subprocess.run(["ip", "netns", "delete", netns], capture_output=True, timeout=10)


def _owner_alive(owner: str) -> bool:
    if owner == CLI_TAG or not owner.isdigit():
        return False
    try:
        os.kill(int(owner), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def cleanup_stale(prefix: str = "skel", include_cli: bool = False) -> list[str]:
    """Remove namespaces left by a crashed run of this harness; returns the names removed.

    A namespace belongs to a run whose pid is part of its name; it is stale when that
    process is gone. Namespaces made by the `up` command are removed only with include_cli.
    """
    pattern = re.compile(rf"^{re.escape(prefix)}-(\d+|{CLI_TAG})(?:-[0-9a-f]{{4}})?-(?:br|h\d+)$")
    removed = []
    # Host namespaces first, so their veths go before the bridge they are enslaved to.
    for netns in sorted(_netns_list(), key=lambda name: name.endswith("-br")):
        match = pattern.match(netns)
        if not match:
            continue
        owner = match.group(1)
        if owner == CLI_TAG and not include_cli:
            continue
        if owner != CLI_TAG and _owner_alive(owner):
            continue
        _delete_netns(netns)
        removed.append(netns)
    return removed


def require_root() -> None:
    """Skip (under pytest) where namespaces cannot be made: not root, or no `ip`."""
    if os.geteuid() != 0:
        import pytest

        pytest.skip("network namespaces need root (CI runs as root)")
    require_command("ip", "iproute2")


def require_command(name: str, package: str) -> None:
    """Skip (under pytest) a test that needs a command this machine lacks, saying why."""
    if shutil.which(name) is None:
        import pytest

        pytest.skip(f"`{name}` is not installed (Debian {package}; `make test` installs it when run as root)")


class Hosts:
    """N hosts in network namespaces on one bridge; a context manager that removes them all."""

    def __init__(self, n: int, prefix: str = "skel", *, tag: str | None = None,
                 snooping: bool = False) -> None:
        if not 1 <= n <= 200:
            raise ValueError(f"Hosts: n={n}, expected 1..200")
        self.prefix = prefix
        tag = tag or f"{os.getpid()}-{secrets.token_hex(2)}"
        self._base = f"{prefix}-{tag}"
        self.bridge_netns = f"{self._base}-br"
        self.names: list[str] = [f"{prefix}h{i}" for i in range(1, n + 1)]
        self._netns = {name: f"{self._base}-h{i}" for i, name in enumerate(self.names, start=1)}
        self._addr = {name: f"{SUBNET}.{i}" for i, name in enumerate(self.names, start=1)}
        self._procs: list[subprocess.Popen[Any]] = []
        self._closed = False
        self._snooping = snooping
        atexit.register(self.close)  # a test that forgets `with` still leaves nothing behind
        try:
            self._build()
        except BaseException:
            self.close()
            raise

    # --- set-up ------------------------------------------------------------------
    def _build(self) -> None:
        br = self.bridge_netns
        _ip("netns", "add", br)
        _ip("-n", br, "link", "set", "lo", "up")
        _ip("-n", br, "link", "add", BRIDGE, "type", "bridge")
        # snooping: the bridge forwards a group only to the hosts that joined it, as a lab
        # switch that snoops IGMP does; it is the querier (without one, snooping ends up
        # forwarding multicast to no port). Otherwise every host gets every group.
        snoop = ("mcast_snooping", "1", "mcast_querier", "1") if self._snooping else ("mcast_snooping", "0")
        _ip("-n", br, "link", "set", BRIDGE, "type", "bridge", *snoop)
        _ip("-n", br, "link", "set", BRIDGE, "up")
        _no_bridge_firewall(br)
        for i, name in enumerate(self.names, start=1):
            netns, port = self._netns[name], f"vh{i}"
            _ip("netns", "add", netns)
            # Created inside the bridge namespace, the pair never touches the root namespace.
            _ip("-n", br, "link", "add", port, "type", "veth", "peer", "name", HOST_IF, "netns", netns)
            _ip("-n", br, "link", "set", port, "master", BRIDGE, "up")
            _ip("-n", netns, "link", "set", "lo", "up")
            _ip("-n", netns, "addr", "add", f"{self._addr[name]}/24", "dev", HOST_IF)
            _ip("-n", netns, "link", "set", HOST_IF, "multicast", "on", "up")
            _ip("-n", netns, "route", "add", "224.0.0.0/4", "dev", HOST_IF)

    # --- queries -----------------------------------------------------------------
    def netns(self, host: str) -> str:
        """The network namespace's name (for `ip netns exec`)."""
        try:
            return self._netns[host]
        except KeyError:
            raise KeyError(f"no host {host!r}; hosts are {self.names}") from None

    def address(self, host: str) -> str:
        self.netns(host)
        return self._addr[host]

    # --- running things in a host ------------------------------------------------------
    def wrap(self, host: str, argv: Sequence[str]) -> list[str]:
        """argv run in the host's network namespace with a private UTS namespace named after it."""
        return _wrap(self.netns(host), host, argv)

    def popen(self, host: str, argv: list[str], **kw: Any) -> subprocess.Popen[Any]:
        """Start argv in the host; nsenter, unshare and sh all exec, so .pid is argv's own."""
        proc = subprocess.Popen(self.wrap(host, argv), **kw)
        self._procs.append(proc)
        return proc

    def run(self, host: str, argv: list[str], **kw: Any) -> subprocess.CompletedProcess[Any]:
        kw.setdefault("timeout", 60)
        return subprocess.run(self.wrap(host, argv), **kw)

    def ping(self, src: str, dst: str, timeout_s: float = 2.0) -> bool:
        """One ICMP echo from src to dst's address (no `ping` binary needed: a raw socket, as root)."""
        code = (
            "import socket,sys,struct,time\n"
            "s=socket.socket(socket.AF_INET,socket.SOCK_RAW,socket.IPPROTO_ICMP)\n"
            f"s.settimeout({timeout_s})\n"
            "h=struct.pack('!BBHHH',8,0,0,0x5b,1)+b'skel'\n"
            "c=sum(struct.unpack('!%dH'%(len(h)//2),h));c=(c>>16)+(c&0xffff);c=~(c+(c>>16))&0xffff\n"
            "s.sendto(h[:2]+struct.pack('!H',c)+h[4:],(sys.argv[1],0))\n"
            "end=time.monotonic()+" + str(timeout_s) + "\n"
            "while time.monotonic()<end:\n"
            "    d,a=s.recvfrom(1500)\n"
            "    if a[0]==sys.argv[1] and d[20]==0: sys.exit(0)\n"
            "sys.exit(1)\n"
        )
        done = self.run(src, [sys.executable, "-c", code, self.address(dst)], capture_output=True,
                        timeout=timeout_s + 10)
        return done.returncode == 0

    # --- loss injection --------------------------------------------------------------
    def drop_inbound(self, host: str, percent: int, udp_port: int | None = None) -> None:
        """Drop `percent` % of the UDP other hosts send to this one (what it sends itself is untouched).

        nftables, since this kernel has no netem. A datagram larger than one frame is
        fragmented and each fragment is dropped on its own chance when no port is given;
        with a port only first fragments match (later ones carry no UDP header).
        """
        if not 0 <= percent <= 100:
            raise ValueError(f"drop_inbound: percent={percent}, expected 0..100")
        require_command("nft", "nftables")
        if percent == 0:
            self.clear_drop(host)
            return
        port = f"udp dport {udp_port} " if udp_port is not None else ""
        chance = f"numgen random mod 100 < {percent} " if percent < 100 else ""  # nft refuses `< 100`
        # Multicast the host loops back to itself also arrives "on" eth0: only others' is lost.
        match = f"iifname {HOST_IF} ip saddr != {self.address(host)} meta l4proto udp {port}{chance}"
        script = (
            f"table inet {NFT_TABLE}\n"
            f"delete table inet {NFT_TABLE}\n"
            f"table inet {NFT_TABLE} {{\n"
            "  chain input {\n"
            "    type filter hook input priority -10; policy accept;\n"
            f"    {match}drop\n"
            "  }\n"
            "}\n"
        )
        _check(["ip", "netns", "exec", self.netns(host), "nft", "-f", "-"], stdin=script)

    def clear_drop(self, host: str) -> None:
        script = f"table inet {NFT_TABLE}\ndelete table inet {NFT_TABLE}\n"
        _check(["ip", "netns", "exec", self.netns(host), "nft", "-f", "-"], stdin=script)

    # --- tear-down ---------------------------------------------------------------------
    def close(self) -> None:
        """Kill every process in the hosts and delete all namespaces (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for proc in self._procs:
            if proc.poll() is None:
                proc.kill()
        for proc in self._procs:
            try:
                proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                pass
        for netns in [*self._netns.values(), self.bridge_netns]:
            if netns in _netns_list():
                _delete_netns(netns)
        atexit.unregister(self.close)

    def detach(self) -> None:
        """Leave the namespaces in place when this object goes (the `up` command)."""
        self._closed = True
        atexit.unregister(self.close)

    def __enter__(self) -> Hosts:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


# --- command line ------------------------------------------------------------------------
def _cli_hosts(prefix: str) -> dict[str, str]:
    """host name → namespace for the hosts `up` made."""
    found = {}
    for netns in _netns_list():
        match = re.match(rf"^{re.escape(prefix)}-{CLI_TAG}-h(\d+)$", netns)
        if match:
            found[f"{prefix}h{match.group(1)}"] = netns
    return found


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m tests.netns.hosts",
                                     description="Hosts in network namespaces on one bridge (root only).")
    parser.add_argument("--prefix", default="skel")
    sub = parser.add_subparsers(dest="command", required=True)
    p = sub.add_parser("up", help="create N hosts and leave them running")
    p.add_argument("n", type=int)
    sub.add_parser("down", help="remove the hosts `up` made and any crashed run's namespaces")
    p = sub.add_parser("exec", help="run a command in a host (its network and host name)")
    p.add_argument("host")
    p.add_argument("cmd", nargs=argparse.REMAINDER)
    args = parser.parse_args(argv)
    if os.geteuid() != 0:
        print("network namespaces need root: run this with sudo", file=sys.stderr)
        return 1
    if args.command == "up":
        if _cli_hosts(args.prefix):
            print("hosts are already up: run `down` first", file=sys.stderr)
            return 1
        hosts = Hosts(args.n, args.prefix, tag=CLI_TAG)
        hosts.detach()
        for name in hosts.names:
            print(f"{name}  {hosts.address(name)}  netns {hosts.netns(name)}")
        return 0
    if args.command == "down":
        for netns in cleanup_stale(args.prefix, include_cli=True):
            print(f"removed {netns}")
        return 0
    netns = _cli_hosts(args.prefix).get(args.host)
    if netns is None or not args.cmd:
        print(f"no host {args.host!r} (hosts: {sorted(_cli_hosts(args.prefix))}) or no command",
              file=sys.stderr)
        return 1
    wrapped = _wrap(netns, args.host, args.cmd)
    os.execvp(wrapped[0], wrapped)


if __name__ == "__main__":
    sys.exit(main())
