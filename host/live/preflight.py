"""What a run of a system will suffer from on this machine, said before it starts: a warm-up that
fills the run, buffers this machine's sockets cannot receive whole, more busy DPUs than cores.
`skel check` prints these with its own; `skel run` says them before it starts."""

from __future__ import annotations

import os
import socket
from dataclasses import dataclass
from typing import Literal
from urllib.parse import parse_qs, urlsplit

from skeleton.analysis.measure.faults import recv_buf_needed

from ..model import System
from ..sysfile.link import rmem_max

# sleep mode models a dedicated processor by sleeping, so it needs no core of its own.
CORE_HUNGRY = ("cpu", "wall", "work")


@dataclass(frozen=True)
class Check:
    """One finding. `severity` says how bad it is when not ok: warn (works, with a risk) or fail."""

    name: str
    ok: bool
    detail: str
    fix: str = ""
    severity: Literal["warn", "fail"] = "fail"

    @property
    def level(self) -> str:
        return "OK" if self.ok else self.severity.upper()


def warmup_warnings(system: System, run_ns: int | None = None) -> list[str]:
    """Processes whose warm-up fills the run (`run_ns`, default the file's run length)."""
    run_ns = system.run_duration_ns() if run_ns is None else run_ns
    out: list[str] = []
    for p in system.processes:
        warmup_ns = system.run.warmup_cycles * p.period_us * 1000
        if warmup_ns >= run_ns:
            out.append(f"process {p.name}: its warm-up ({system.run.warmup_cycles} cycles of "
                       f"{p.period_us / 1000:g} ms = {warmup_ns / 1e9:g} s) is not shorter than the run "
                       f"({run_ns / 1e9:g} s): none of its cycles would be measured")
    return out


def delivery_warnings(system: System) -> list[str]:
    """Buffers this machine's DPUs read that their sockets cannot receive whole (skel doctor's check)."""
    limit = rmem_max()
    out = []
    for b in system.buffers:
        link = system.link(b.link)
        readers = [p.name for p in system.readers(b.id) if is_this_machine(system.dpu(p.dpu).host)]
        if link.local or not readers:
            continue
        asked = parse_qs(urlsplit(link.url).query).get("recv_buf_size", [None])[-1]
        found = check_buffer_socket(b.name, b.bytes, limit, int(asked) if asked and asked.isdigit() else None)
        if not found.ok:
            out.append(f"{found.name} (link {link.name}, read here by {', '.join(readers)}): {found.detail}; "
                       f"fix: {found.fix}")
    return out


def core_warnings(system: System, load_by_dpu: dict[int, float]) -> list[str]:
    """Busy DPUs that need a core each, on this machine (other hosts' cores are unknown here)."""
    cores = os.cpu_count() or 1
    busy = [d for d in system.dpus
            if is_this_machine(d.host) and d.compute in CORE_HUNGRY and load_by_dpu[d.id] > 0]
    out: list[str] = []
    for host in sorted({d.host for d in busy}):
        mine = [d.id for d in busy if d.host == host]
        if len(mine) > cores:
            out.append(f"host {host}: {len(mine)} busy DPUs ({', '.join(map(str, mine))}) compute in "
                       f"cpu/wall/work mode but this machine has {cores} cores: they will preempt each "
                       "other; use compute: sleep or fewer DPUs")
        pinned: dict[int, int] = {}
        for d in (d for d in busy if d.host == host and d.cpu is not None):
            if d.cpu >= cores:
                out.append(f"DPU {d.id}: cpu {d.cpu} does not exist on this machine ({cores} cores)")
            elif d.cpu in pinned:
                out.append(f"DPU {d.id}: pinned to cpu {d.cpu} like DPU {pinned[d.cpu]}: they share one core")
            pinned.setdefault(d.cpu, d.id)
    return out


def is_this_machine(host: str) -> bool:
    names = {"localhost", "127.0.0.1", "::1", socket.gethostname(), socket.gethostname().split(".")[0]}
    return host in names


def check_buffer_socket(buffer: str, payload_bytes: int, rmem_max: int | None,
                        recv_buf_size: int | None = None) -> Check:
    """Can a reader's socket here hold one message of `buffer` whole? The DPU asks for
    recv_buf_needed() (dpu/link.c); the kernel grants at most net.core.rmem_max, and a
    recv_buf_size written in the link's URL is used as it is."""
    need = recv_buf_needed(payload_bytes)
    name = f"buffer {buffer}"
    if recv_buf_size is not None and recv_buf_size < need:
        return Check(name, False, f"{payload_bytes} bytes: the link's URL asks recv_buf_size="
                     f"{recv_buf_size}, under the {need} bytes one message needs whole: it never arrives",
                     f"recv_buf_size={need} in the link's url (or leave it out)")
    if recv_buf_size is None and rmem_max is not None and rmem_max < need:
        return Check(name, False, f"{payload_bytes} bytes: a reader's socket needs a {need}-byte receive "
                     f"buffer but net.core.rmem_max is {rmem_max}: it would never arrive",
                     f"sysctl -w net.core.rmem_max={need}")
    return Check(name, True, f"{payload_bytes} bytes fit a reader's socket receive buffer")
