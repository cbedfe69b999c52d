"""A link on the wire: each writer's buffers travel on a multicast group and a UDP port of
their own.

The system file names one `udpm://GROUP:PORT` per link; the host gives every process that
writes to it the next group and the next port, GROUP + 1 and PORT + 1, GROUP + 2 and
PORT + 2, ... (in the order of the links, then of the writers' ids; links that name the same
group and port count on together). A DPU opens a socket on the writers it reads (and its
own writers', to send), so it receives only what it reads: its receive cost grows with its
own inputs, not with the whole system's traffic. A group because across hosts a switch (or
bridge) that snoops IGMP forwards a group only to the hosts that joined it, so only a group
of its own keeps a writer's traffic off the hosts that do not read it; on one host a group
or a port alone would do, since LCM binds each receive socket to its group and port (the
ports came first). Control (configs, commands,
events) stays on the first link's GROUP:PORT, the control URL, and what a run records
(heartbeats, timing, reports) travels on its record URL, GROUP - 1:PORT - 1, which only the
host and the logger join: no DPU wakes for another's records (record_url).

`buffer_desc_t.url` carries the result to the DPUs (host/live/wire.py); the rules refuse a
system whose links' ports would overlap or whose groups would leave the multicast range
(host/sysfile/rules.py).
"""

from __future__ import annotations

import ipaddress
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import parse_qs, urlsplit, urlunsplit

from skelmsg.contract import DEFAULT_URL, RECORD_OFFSET

from ..model import Link, control_link

MAX_PORT = 65535
# What the host tool and the logger ask the kernel to buffer on the record URL (capped at
# net.core.rmem_max): every DPU's timing batch comes in the same few milliseconds, after
# the same releases, and a default socket buffer (208 KiB, half of it bookkeeping) held
# the batches of some 10 DPUs: the rest were lost and asked for again, heartbeats with them.
RECORD_RECV_BYTES = 8 * 1024 * 1024
LCM_GROUP, LCM_PORT = urlsplit(DEFAULT_URL).hostname, urlsplit(DEFAULT_URL).port


@dataclass(frozen=True)
class LcmUrl:
    provider: str
    group: str
    port: int
    ttl: int
    recv_buf_size: int | None = None


def _resolved(url: str) -> str:
    """What liblcm opens for `url`: an empty one means $LCM_DEFAULT_URL, else its own default
    (the contract's DEFAULT_URL; a missing group or port means that URL's too)."""
    return url or os.environ.get("LCM_DEFAULT_URL") or DEFAULT_URL


def parse_url(url: str) -> LcmUrl:
    """udpm://GROUP:PORT?ttl=N (LCM's defaults fill what is left out); ValueError says what is wrong."""
    parts = urlsplit(_resolved(url))
    if parts.scheme != "udpm":
        return LcmUrl(parts.scheme, "", 0, 0)
    query = {key: values[-1] for key, values in parse_qs(parts.query).items()}
    for key in ("ttl", "recv_buf_size"):
        if key in query and not re.fullmatch(r"[0-9]+", query[key].strip()):
            raise ValueError(f"{key}={query[key]} in {url!r}: expected a whole number")
    try:
        group = parts.hostname or LCM_GROUP
        port = parts.port or LCM_PORT
        ttl = int(query.get("ttl", "0"))
        recv = int(query["recv_buf_size"]) if "recv_buf_size" in query else None
        address = ipaddress.IPv4Address(group)
    except ValueError as exc:
        raise ValueError(f"{url!r} is not udpm://GROUP:PORT?ttl=N ({exc})") from None
    if not address.is_multicast:
        raise ValueError(f"{group} in {url!r} is not a multicast group (224.0.0.0/4); LCM uses {LCM_GROUP}")
    if not 0 <= ttl <= 255:
        raise ValueError(f"ttl={ttl} in {url!r}: expected 0 (this host) or 1 (the local network)")
    return LcmUrl("udpm", group, port, ttl, recv)


def record_url(control_url: str) -> str:
    """Where a run's records travel (contract: RECORD_OFFSET): the control URL's group and
    port each that much lower, its options kept; dpu/link.c's link_record_url says the same.
    Another provider's URL is its own record URL. ValueError says what is wrong."""
    parsed, parts = parse_url(control_url), urlsplit(_resolved(control_url))
    if parsed.provider != "udpm":
        return _resolved(control_url)
    group = ipaddress.IPv4Address(parsed.group) - RECORD_OFFSET
    if parsed.port <= RECORD_OFFSET or not group.is_multicast:
        raise ValueError(f"{control_url!r}: its record URL, group and port each {RECORD_OFFSET} lower, "
                         "would leave the multicast groups or the ports")
    return urlunsplit((parts.scheme, f"{group}:{parsed.port - RECORD_OFFSET}", parts.path, parts.query,
                       parts.fragment))


def record_listen_url(control_url: str, limit: int | None) -> str:
    """The record URL as its listeners open it: asking for RECORD_RECV_BYTES of socket
    buffer, or `limit` (net.core.rmem_max: LCM warns when it gets less than it asked) when
    that is less, unless the URL asks for a size itself."""
    url = record_url(control_url)
    ask = min(RECORD_RECV_BYTES, limit or 0)
    if parse_url(url).provider != "udpm" or "recv_buf_size=" in url or ask <= 0:
        return url
    return f"{url}{'&' if '?' in url else '?'}recv_buf_size={ask}"


def sysctl(path: str) -> int | None:
    """The integer under /proc/sys/PATH, None when there is none."""
    try:
        return int(Path("/proc/sys", path).read_text().split()[0])
    except (OSError, ValueError, IndexError):
        return None


def rmem_max() -> int | None:
    """net.core.rmem_max: the most socket buffer LCM may ask for (None: unknown)."""
    return sysctl("net/core/rmem_max")


def _base(url: str) -> tuple[str, int]:
    """The group and port a udpm URL names (LCM's defaults fill what it leaves out)."""
    parsed = parse_url(url)
    return parsed.group, parsed.port


def writer_ports(links: Sequence[Link], pairs: Iterable[tuple[int, int]]) -> dict[tuple[int, int], int]:
    """(link id, writer process id) -> the port that writer's buffers on that link travel on.
    `pairs`: every (link id, writer id) in use; local links have none."""
    url = {link.id: link.url for link in links if not link.local}
    out: dict[tuple[int, int], int] = {}
    taken: dict[tuple[str, int], int] = {}
    for link_id, writer in sorted(set(pairs)):
        if link_id in url:
            base = _base(url[link_id])
            taken[base] = taken.get(base, 0) + 1
            out[link_id, writer] = base[1] + taken[base]
    return out


def writer_url(url: str, port: int) -> str:
    """The URL of a writer given `port` on link `url`: as many groups on as ports on, its
    options (ttl, recv_buf_size) kept."""
    group, base = _base(url)
    parts = urlsplit(url)
    moved = ipaddress.IPv4Address(group) + (port - base)
    return urlunsplit((parts.scheme, f"{moved}:{port}", parts.path, parts.query, parts.fragment))


def _outside_groups(group: str, count: int) -> str | None:
    """Why GROUP + 1 .. GROUP + count are not all usable multicast groups, or None. (count is
    below 65536: the ports are checked first, so the sum stays an IPv4 address.)"""
    first, last = ipaddress.IPv4Address(group) + 1, ipaddress.IPv4Address(group) + count
    local = ipaddress.IPv4Network("224.0.0.0/24")  # routers and switches flood it: never snooped
    if not last.is_multicast or first in local or last in local:
        top = ipaddress.IPv4Address("239.255.255.255") - count
        return (f"its writers need groups {first}..{last}, outside the multicast groups a switch "
                f"can keep apart (224.0.1.0-239.255.255.255): give the link a group from 224.0.1.0 "
                f"to {top}")
    # A switch snoops by Ethernet address, which keeps only a group's low 23 bits: those that
    # 224.0.0.x has (239.0.0.x, 239.128.0.x, ...) are flooded as it is.
    flooded = next((first + i for i in range(count) if (int(first) + i) & 0x7FFFFF < 256), None)
    if flooded is not None:
        return (f"its writers need groups {first}..{last}, and {flooded} shares its Ethernet address with "
                f"224.0.0.{int(flooded) & 0xFF}, which switches flood to every host: give the link a "
                "group whose writers' groups stay clear of x.0.0.0-x.0.0.255 and x.128.0.0-x.128.0.255")
    return None


Spans = dict[tuple[str, int], tuple[Link, int]]


def _spans(links: Sequence[Link], ports: dict[tuple[int, int], int]) -> Spans:
    """Per base group and port in use: the first link naming it and the last port its writers take."""
    spans: Spans = {}
    for link in links:
        if link.local:
            continue
        base = _base(link.url)
        last = max((p for (link_id, _), p in ports.items() if link_id == link.id), default=base[1])
        first, was = spans.get(base, (link, base[1]))
        spans[base] = (first, max(was, last))
    return spans


def port_clash(links: Sequence[Link], ports: dict[tuple[int, int], int]) -> tuple[Link, str] | None:
    """A link whose ports (its own and its writers') run past 65535 or into another link's,
    or whose writers' groups leave the multicast range, with what to say; None when every
    link has its ports and groups to itself."""
    spans = _spans(links, ports)
    control = control_link(links)
    record = record_url(control.url) if control is not None else ""
    record_port = parse_url(record).port if record else None
    for (group, port), (link, last) in spans.items():
        if record_port is not None and port < record_port <= last:
            return link, (f"its writers' buffers take ports {port + 1}..{last}, which hold port "
                          f"{record_port} of the record URL ({record}: the DPUs' heartbeats and timing); put "
                          "the link's port further from the control URL's")
        if last > MAX_PORT:
            return link, f"its writers need ports {port + 1}..{last}, past {MAX_PORT}"
        if last > port and (why := _outside_groups(group, last - port)) is not None:
            return link, why
        for (other_group, other), (them, their_last) in spans.items():
            if them is not link and port <= their_last and other <= last:
                return link, (f"its writers' buffers take ports {port}..{last}, which meet link "
                              f"{them.name}'s {other}..{their_last} ({other_group}): on one host a "
                              "port is shared by every group; put the links' ports further apart")
    return None


def group_overlap(links: Sequence[Link], ports: dict[tuple[int, int], int], control_url: str) -> str | None:
    """Two links whose writers' groups meet, or writers on the control or record group, said
    as a warning; None when every writer's group is its own. Their ports differ (port_clash),
    so every buffer still reaches its readers and no others; but a switch that snoops IGMP
    forwards a group to every host that joined it for either."""
    shared = {int(ipaddress.IPv4Address(parse_url(url).group)): what
              for url, what in ((record_url(control_url), "record"), (control_url, "control"))}
    # A link's own group carries nothing of its writers (only the control URL's carries control).
    groups = [(link, int(ipaddress.IPv4Address(group)) + 1, last - port)
              for (group, port), (link, last) in _spans(links, ports).items() if last > port]
    for i, (link, first, count) in enumerate(groups):
        for group, what in shared.items():
            if first <= group < first + count:
                return (f"link {link.name}'s writers' groups {ipaddress.IPv4Address(first)}.."
                        f"{ipaddress.IPv4Address(first + count - 1)} hold the {what} group "
                        f"{ipaddress.IPv4Address(group)}, which every host joins: a writer's buffers there "
                        f"go to every host; move link {link.name}'s group so that its writers' leave it out")
        for them, their_first, their_count in groups[i + 1:]:
            if first < their_first + their_count and their_first < first + count:
                shared = (ipaddress.IPv4Address(max(first, their_first)),
                          ipaddress.IPv4Address(min(first + count, their_first + their_count) - 1))
                after = ipaddress.IPv4Address(first + count)
                return (f"links {link.name} and {them.name} share their writers' multicast groups "
                        f"{shared[0]}..{shared[1]}: a switch that snoops IGMP then sends each link's "
                        f"buffers on them to the hosts of both; give link {them.name} a group from "
                        f"{after} on")
    return None
