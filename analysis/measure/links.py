"""The report's table of the network: per link, what its writers offered it, against its
bandwidth, what its readers lost and how long its buffers took, beside what the file models.

Offered is measured: each writer's completed cycles in the window publish each of its
buffers once, over the time its DPU measured, in bytes on the wire (Buffer.wire_bytes, the
prediction's own count; a `local` link's, the payload). The emulated transport does not
queue buffers behind each other yet: a link over its bandwidth is said saturated, and its
buffers are not delayed by it.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from skeleton.host.model import System

from .latency import BufferMetrics
from .metrics import DpuMetrics, ProcessMetrics


@dataclass
class LinkMetrics:
    link: str
    buffers: int  # the buffers it carries
    messages_per_s: float | None  # its writers' messages, per second each writer's DPU measured
    offered_mbps: float | None  # those messages' bytes on the wire, Mbit/s
    bandwidth_mbps: float | None  # the file's (or its preset's); None: not given
    utilization_pct: float | None  # offered over the bandwidth
    saturated: bool  # offered more than the bandwidth
    lost: int  # versions its readers never received (over every reader)
    lost_pct: float | None  # of those they received or lost
    modelled_loss_pct: float  # the long-run loss its emulation draws
    modelled_delay_us: float  # the mean delay its emulation adds
    transport_p99_us: float | None  # the largest p99 of its buffers' transport (send to seen)
    transport_max_us: float | None


def link_metrics(system: System, buffers: Sequence[BufferMetrics], processes: Sequence[ProcessMetrics],
                 dpus: Sequence[DpuMetrics]) -> list[LinkMetrics]:
    """Per link of `system` that carries a buffer, from a window's tables."""
    cycles = {p.id: p.cycles for p in processes}
    elapsed_s = {d.id: d.elapsed_ms / 1000 for d in dpus if d.elapsed_ms}
    measured = {b.buffer_id: b for b in buffers}
    out = []
    for link in system.links:
        mine = [b for b in system.buffers if b.link == link.id]
        if not mine:
            continue
        rates = {}
        for b in mine:
            writer = system.find_process(b.writer)
            if writer is not None and writer.dpu in elapsed_s:
                rates[b.id] = cycles.get(writer.id, 0) / elapsed_s[writer.dpu]
        whole = len(rates) == len(mine)
        messages = sum(rates.values()) if whole else None
        offered = (sum(rates[b.id] * 8 * (b.bytes if link.local else b.wire_bytes) for b in mine) / 1e6
                   if whole else None)
        utilization = (100 * offered / link.bandwidth_mbps
                       if offered is not None and link.bandwidth_mbps else None)
        read = [measured[b.id] for b in mine if b.id in measured]
        lost = sum(b.lost for b in read)
        reached = sum(r.received + r.lost for b in read for r in b.readers)
        p99 = [b.latency_us.p99 for b in read if b.latency_us.p99 is not None]
        most = [b.latency_us.max for b in read if b.latency_us.max is not None]
        out.append(LinkMetrics(
            link=link.name, buffers=len(mine), messages_per_s=messages, offered_mbps=offered,
            bandwidth_mbps=link.bandwidth_mbps, utilization_pct=utilization,
            saturated=utilization is not None and utilization > 100,
            lost=lost, lost_pct=100 * lost / reached if reached else None,
            modelled_loss_pct=link.mean_loss_pct, modelled_delay_us=link.delay_us[1],
            transport_p99_us=max(p99, default=None), transport_max_us=max(most, default=None)))
    return out
