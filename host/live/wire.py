"""A validated System in its outward forms: the config_t every DPU configures
itself from, and a YAML file with every default made explicit.

With host/model.py's from_config (the way back, and the enums both use), the only place
that knows how the system file maps onto lcmtypes/config_t.lcm; DPUs see ids and enums
only, never names they would have to resolve, except an event's: its name is its channel
(EVENT_CHANNEL_PREFIX + name), whoever sends it.
"""

from __future__ import annotations

import dataclasses
import math
import time
from typing import Any

import yaml

import skelmsg

from ..model import COMPUTE, EVENT_KIND, EXECUTIVE, NETWORK, SYNC, Event, Link, System
from ..sysfile.schema import COSTS
from ..theory.predict import planned_data_us


def config_message(system: System, generation: int, run_id: int, committed: bool) -> skelmsg.config_t:
    msg = skelmsg.config_t()
    msg.generation = generation
    msg.run_id = run_id
    msg.sent_utc_ns = time.time_ns()
    msg.committed = 1 if committed else 0
    msg.system = system.name
    msg.warmup_cycles = system.run.warmup_cycles
    msg.lockout_cycles = system.run.lockout_cycles
    msg.late_pct = system.run.late_pct
    msg.too_late_pct = system.run.too_late_pct
    msg.seed = system.run.seed
    msg.network = NETWORK[system.run.network]
    msg.links = [_link(link) for link in system.links]
    msg.nlinks = len(msg.links)
    msg.dpus = []
    for d in system.dpus:
        dpu = skelmsg.dpu_t()
        dpu.id, dpu.host, dpu.cpu = d.id, d.host, -1 if d.cpu is None else d.cpu
        dpu.compute, dpu.executive, dpu.speed = COMPUTE[d.compute], EXECUTIVE[d.executive], d.speed
        dpu.minor_cycle_us = d.minor_cycle_us
        dpu.links = list(d.links)
        dpu.nlinks = len(dpu.links)
        msg.dpus.append(dpu)
    msg.ndpus = len(msg.dpus)
    msg.buffers = []
    for b in system.buffers:
        buf = skelmsg.buffer_desc_t()
        buf.id, buf.name, buf.bytes, buf.link, buf.writer, buf.channel = (
            b.id, b.name, b.bytes, b.link, b.writer, b.channel)
        buf.url = system.buffer_url(b.id)
        msg.buffers.append(buf)
    msg.nbuffers = len(msg.buffers)
    msg.processes = []
    data_us = planned_data_us(system)
    for p in system.processes:
        proc = skelmsg.process_t()
        proc.id, proc.name, proc.dpu, proc.order = p.id, p.name, p.dpu, p.order
        proc.period_us, proc.compute_us, proc.sync = p.period_us, p.compute_us, SYNC[p.sync]
        proc.priority = p.priority
        # rounded up: a wait the schedule plans to the µs is on schedule, never late by rounding
        proc.ready_us = math.ceil(data_us.get(p.id, 0.0))
        proc.inputs = list(p.inputs)
        proc.required = [1 if b in p.required else 0 for b in p.inputs]
        proc.ninputs = len(proc.inputs)
        proc.outputs = list(p.outputs)
        proc.noutputs = len(proc.outputs)
        proc.quantiles_us = list(p.varying.quantiles_us) if p.varying else []
        proc.nquantiles = len(proc.quantiles_us)
        proc.event, proc.queue = p.event, p.queue
        proc.emits, proc.nemits = list(p.emits), len(p.emits)
        proc.library, proc.function = (p.code.library, p.code.function) if p.code else ("", "")
        msg.processes.append(proc)
    msg.nprocesses = len(msg.processes)
    msg.chains = []
    for c in system.chains:
        chain = skelmsg.chain_t()
        chain.name, chain.processes, chain.nprocesses = c.name, list(c.processes), len(c.processes)
        msg.chains.append(chain)
    msg.nchains = len(msg.chains)
    msg.events = [_event_source(e) for e in system.events]
    msg.nevents = len(msg.events)
    msg.source = system.source_text
    return msg


def _event_source(e: Event) -> skelmsg.event_source_t:
    src = skelmsg.event_source_t()
    src.name, src.kind, src.dpu = e.name, EVENT_KIND[e.kind], e.dpu
    src.period_us, src.jitter_us, src.rate_hz = e.period_us, e.jitter_us, e.rate_hz
    src.count, src.spacing_us = e.count, e.spacing_us
    return src


def _link(link: Link) -> skelmsg.link_t:
    msg = skelmsg.link_t()
    msg.id, msg.name, msg.url = link.id, link.name, "" if link.local else link.url
    msg.latency_us, msg.jitter_us, msg.loss_pct = link.latency_us, link.jitter_us, link.loss_pct
    msg.jitter = skelmsg.link_t.JITTER_NORMAL if link.jitter == "normal" else skelmsg.link_t.JITTER_UNIFORM
    if link.burst is not None:
        msg.burst_enter_pct, msg.burst_leave_pct = link.burst.enter_pct, link.burst.leave_pct
        msg.burst_loss_pct = link.burst.loss_pct
    msg.per_message_us, msg.per_byte_ns = link.per_message_us, link.per_byte_ns
    msg.push_byte_ns, msg.remote_read_us = link.push_byte_ns, link.remote_read_us
    msg.bandwidth_mbps, msg.queue_us = link.bandwidth_mbps or 0.0, link.queue_us
    return msg


def _transport(link: Link) -> dict[str, Any]:
    """A link's emulated transport and its costs as the file gives them: only what differs from none."""
    out: dict[str, Any] = {}
    if link.bandwidth_mbps:
        out |= {"bandwidth_mbps": link.bandwidth_mbps, "queue_us": link.queue_us}
    if link.latency_us or link.jitter_us:
        out |= {"latency_us": link.latency_us, "jitter_us": link.jitter_us, "jitter": link.jitter}
    if link.loss_pct:
        out["loss_pct"] = link.loss_pct
    if link.burst is not None:
        out["loss_burst"] = {"enter_pct": link.burst.enter_pct, "leave_pct": link.burst.leave_pct,
                             "loss_pct": link.burst.loss_pct}
    # its CPU costs as charged (a preset's filled in): only those it has
    out |= {k: v for k in COSTS if (v := getattr(link, k))}
    return out


def dump_yaml(system: System) -> str:
    """The system with every default made explicit; loading it gives the same system."""
    names = {b.id: b.name for b in system.buffers}
    links = {link.id: link.name for link in system.links}
    doc: dict[str, Any] = {
        "system": system.name,
        "links": [{"name": link.name, "url": link.url, **_transport(link)} for link in system.links],
        "dpus": [{"id": d.id, "host": d.host, "cpu": d.cpu, "compute": d.compute, "executive": d.executive,
                  "speed": d.speed, "minor_cycle_us": d.minor_cycle_us, "links": [links[i] for i in d.links]}
                 for d in system.dpus],
        "buffers": [{"id": b.id, "name": b.name, "bytes": b.bytes, "link": links[b.link]}
                    for b in system.buffers],
        "processes": [{"id": p.id, "name": p.name, "dpu": p.dpu, "order": p.order, "period_us": p.period_us,
                       "compute_us": p.varying.given if p.varying else p.compute_us,
                       **({"compute": dataclasses.asdict(p.code)} if p.code else {}),
                       "sync": p.sync, **({"priority": p.priority} if p.priority else {}),
                       "inputs": [names[b] for b in p.inputs],
                       **({"required": [names[b] for b in p.required]} if p.sync == "data" else {}),
                       **({"event": p.event, "queue": p.queue} if p.sync == "event" else {}),
                       **({"emits": list(p.emits)} if p.emits else {}),
                       "outputs": [names[b] for b in p.outputs]} for p in system.processes],
        "run": _given(system.run),
        "chains": [{"name": c.name, "processes": [system.process(i).name for i in c.processes]}
                   for c in system.chains],
    }
    if system.events:
        doc["events"] = [{k: v for k, v in dataclasses.asdict(e).items() if v or k in ("name", "kind")}
                         for e in system.events]
    if system.reference is not None:
        doc["reference"] = _given(system.reference)
    return yaml.safe_dump(doc, sort_keys=False)


def _given(record: Any) -> Any:
    """A model record as the file writes it: mappings and lists, fields without a value left out."""
    if dataclasses.is_dataclass(record):
        return {k: _given(v) for k, v in dataclasses.asdict(record).items() if v is not None}
    if isinstance(record, dict):
        return {k: _given(v) for k, v in record.items() if v is not None}
    return list(record) if isinstance(record, tuple) else record
