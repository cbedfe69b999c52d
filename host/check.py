"""`skel check`: validate a system file and show what it asks of each DPU.

Static analysis only (nothing is started): per DPU its host, minor cycle,
processes and static load Σ compute/period, with warnings for what a run would
suffer from: an overloaded DPU, more busy DPUs than cores, a warm-up longer
than the run, a buffer too large for this machine's socket receive buffers.
"""

from __future__ import annotations

import json
import os
import socket
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO
from urllib.parse import parse_qs, urlsplit

from rich.console import Console, JustifyMethod
from rich.table import Table

from ..analysis.exitcodes import EXIT_BAD_INPUT, EXIT_OK
from .doctor import check_buffer_socket, rmem_max
from .system import System, SystemFileError, load

# sleep mode models a dedicated processor by sleeping, so it needs no core of its own.
CORE_HUNGRY = ("cpu", "wall", "work")


def check(path: str | Path, overrides: Sequence[str] = (), as_json: bool = False,
          out: TextIO | None = None) -> int:
    """0 when the file is valid (warnings included), 2 when it is not."""
    out = out or sys.stdout
    try:
        system = load(path, overrides)
    except SystemFileError as e:
        print(e, file=sys.stderr)
        return EXIT_BAD_INPUT
    summary = summarize(system)
    if as_json:
        out.write(json.dumps(summary, indent=2) + "\n")  # one write: `| head` is no broken pipe
    else:
        _print(system, summary, out)
    return EXIT_OK


def summarize(system: System) -> dict[str, Any]:
    load_by_dpu, worst_by_dpu = system.static_load(), system.static_load(worst=True)
    dpus = [
        {
            "id": d.id,
            "host": d.host,
            "compute": d.compute,
            "executive": d.executive,
            "minor_cycle_ms": d.minor_cycle_us / 1000,
            "processes": [p.name for p in system.processes_on(d.id)],
            **({"priorities": {p.name: p.priority for p in system.processes_on(d.id)}}
               if d.executive == "threads" else {}),
            "static_load_pct": round(100 * load_by_dpu[d.id], 1),
            "worst_load_pct": round(100 * worst_by_dpu[d.id], 1),
        }
        for d in system.dpus
    ]
    varying = [
        {"process": p.name, "kind": p.varying.kind, "min_us": round(p.varying.min_us, 1),
         "mean_us": round(p.varying.mean_us, 1), "max_us": round(p.varying.max_us, 1)}
        for p in system.processes if p.varying
    ]
    return {"system": system.name, "dpus": dpus, "varying_compute": varying, "warnings": warnings(system)}


def warnings(system: System) -> list[str]:
    out: list[str] = []
    load_by_dpu = system.static_load()
    worst_by_dpu = system.static_load(worst=True)
    for d in system.dpus:
        if load_by_dpu[d.id] > 1.0:
            out.append(f"DPU {d.id}: static load {100 * load_by_dpu[d.id]:.1f} % exceeds 100 %: "
                       "it will overrun every cycle; a lockout is likely")
        elif worst_by_dpu[d.id] > 1.0:
            out.append(f"DPU {d.id}: static load {100 * load_by_dpu[d.id]:.1f} % on average but "
                       f"{100 * worst_by_dpu[d.id]:.1f} % when its varying computations draw their maximum: "
                       "cycles with long draws will overrun")
    out += _core_warnings(system, load_by_dpu)
    out += warmup_warnings(system)
    out += delivery_warnings(system)
    return out


def delivery_warnings(system: System) -> list[str]:
    """Buffers this machine's DPUs read that their sockets cannot receive whole (skel doctor's check)."""
    limit = rmem_max()
    out = []
    for b in system.buffers:
        link = system.link(b.link)
        readers = [p.name for p in system.readers(b.id) if _is_this_machine(system.dpu(p.dpu).host)]
        if link.local or not readers:
            continue
        asked = parse_qs(urlsplit(link.url).query).get("recv_buf_size", [None])[-1]
        found = check_buffer_socket(b.name, b.bytes, limit, int(asked) if asked and asked.isdigit() else None)
        if not found.ok:
            out.append(f"{found.name} (link {link.name}, read here by {', '.join(readers)}): {found.detail}; "
                       f"fix: {found.fix}")
    return out


def _core_warnings(system: System, load_by_dpu: dict[int, float]) -> list[str]:
    """Busy DPUs that need a core each, on this machine (other hosts' cores are unknown here)."""
    cores = os.cpu_count() or 1
    busy = [d for d in system.dpus
            if _is_this_machine(d.host) and d.compute in CORE_HUNGRY and load_by_dpu[d.id] > 0]
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


def _is_this_machine(host: str) -> bool:
    names = {"localhost", "127.0.0.1", "::1", socket.gethostname(), socket.gethostname().split(".")[0]}
    return host in names


def _print(system: System, summary: dict[str, Any], out: TextIO) -> None:
    console = Console(file=out, highlight=False, width=max(100, Console(file=out).width))
    run = (f"{system.run.cycles} cycles of {system.critical_period_us / 1000:g} ms"
           if system.run.cycles is not None else f"{system.run.duration_s:g} s")
    console.print(f"system [bold]{system.name}[/] ({system.path}): {len(system.dpus)} DPUs, "
                  f"{len(system.processes)} processes, {len(system.buffers)} buffers; run {run}",
                  soft_wrap=True)
    table = Table(box=None, pad_edge=False)
    columns: tuple[tuple[str, JustifyMethod], ...] = (
        ("DPU", "right"), ("host", "left"), ("compute", "left"), ("minor cycle ms", "right"),
        ("processes", "left"), ("static load %", "right"))
    for title, justify in columns:
        table.add_column(title, justify=justify)
    for d in summary["dpus"]:
        pct = d["static_load_pct"]
        prio = d.get("priorities", {})
        names = [f"{n} (priority {prio[n]})" if n in prio else n for n in d["processes"]]
        load = f"[red]{pct:.1f}[/]" if pct > 100 else f"{pct:.1f}"
        tasking = " tasking" if d["executive"] == "threads" else ""
        table.add_row(str(d["id"]), d["host"], d["compute"] + tasking,
                      f"{d['minor_cycle_ms']:g}", ", ".join(names), load)
    console.print(table)
    for v in summary["varying_compute"]:
        console.print(f"compute of {v['process']} varies: {v['kind']}, {v['min_us']:g} to "
                      f"{v['max_us']:g} us, mean {v['mean_us']:g} us (the static load counts the mean)",
                      soft_wrap=True)
    for w in summary["warnings"]:
        console.print(f"[yellow]WARN[/] {w}", soft_wrap=True)
    if not summary["warnings"]:
        console.print("valid, no warnings")
