"""The report's table of the network: per link, what its writers offered it, against its
bandwidth, what its readers lost and how long its buffers took, beside what the file models.

Offered is measured: each writer's completed cycles in the window publish each of its
buffers once, over the time its DPU measured, in bytes on the wire (Link.message_bytes, the
prediction's own count; a `local` link's, the payload). On a bandwidth-limited link the
readers' DPUs queue every message for one emulated transmitter (model.Bus): its wait shows in
the transport beyond the latency and the buffer's own time on the wire, beside the model's
longest wait; a saturated link's full queue drops, counted as lost.
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
    lost_bytes_pct: float | None  # the same, weighed by each message's bytes on the link
    modelled_loss_pct: float  # the long-run loss its emulation draws, and its full queue drops (model.Bus)
    modelled_delay_us: float  # the mean latency its emulation adds
    transport_p99_us: float | None  # the largest p99 of its buffers' transport (send to seen)
    transport_max_us: float | None
    modelled_queue_us: float  # bandwidth-limited: the longest a message waits for the transmitter
    queue_p99_us: float | None  # the largest p99 of its buffers' transport less latency and own wire time


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
        offered = sum(rates[b.id] * 8 * link.message_bytes(b) for b in mine) / 1e6 if whole else None
        utilization = (100 * offered / link.bandwidth_mbps
                       if offered is not None and link.bandwidth_mbps else None)
        read = [measured[b.id] for b in mine if b.id in measured]
        lost = sum(b.lost for b in read)
        reached = sum(r.received + r.lost for b in read for r in b.readers)
        size = {b.buffer_id: link.message_bytes(system.buffer(b.buffer_id)) for b in read}
        bytes_reached = sum(size[b.buffer_id] * (r.received + r.lost) for b in read for r in b.readers)
        bytes_lost = sum(size[b.buffer_id] * b.lost for b in read)
        p99 = [b.latency_us.p99 for b in read if b.latency_us.p99 is not None]
        most = [b.latency_us.max for b in read if b.latency_us.max is not None]
        bus = system.buses.get(link.id)
        queued = [b.latency_us.p99 - link.delay_us[1] - link.wire_us(system.buffer(b.buffer_id))
                  for b in read if bus is not None and b.latency_us.p99 is not None]
        out.append(LinkMetrics(
            link=link.name, buffers=len(mine), messages_per_s=messages, offered_mbps=offered,
            bandwidth_mbps=link.bandwidth_mbps, utilization_pct=utilization,
            saturated=utilization is not None and utilization > 100,
            lost=lost, lost_pct=100 * lost / reached if reached else None,
            lost_bytes_pct=100 * bytes_lost / bytes_reached if bytes_reached else None,
            modelled_loss_pct=system.lost_pct(link.id), modelled_delay_us=link.delay_us[1],
            transport_p99_us=max(p99, default=None), transport_max_us=max(most, default=None),
            modelled_queue_us=bus.most_wait_us if bus is not None else 0.0,
            queue_p99_us=max(queued, default=None)))
    return out
