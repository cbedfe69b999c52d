"""The system file's cross-reference rules: what per-field checks cannot see.

resolve() checks the references between sections (DPUs, links, buffers,
processes, chains), fills the defaults that depend on other sections (a
buffer's link, a DPU's minor cycle, a process's order) and returns plain
records. Rules run in file order, so the first broken one is always the same;
it is raised as Invalid(field path, problem).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from skeleton.analysis.errors import EXIT_BAD_INPUT, SkelError
from skelmsg import contract

from ..model import Buffer, Chain, Code, Dpu, Event, Link, LossBurst, Process, Varying, charges, control_link
from .compute import ComputeError, varying
from .link import parse_url, port_clash, record_url, writer_ports
from .schema import (
    ABSURD_COMPUTE_PERIODS,
    COSTS,
    DEFAULT_LINK,
    QUEUE_US,
    BufferSpec,
    ComputeSpec,
    LinkSpec,
    ProcessSpec,
    SystemSpec,
)
from .yamlfile import did_you_mean, show


class Invalid(SkelError):
    """A rule across sections broken (system.py makes it a SystemFileError)."""

    exit_code = EXIT_BAD_INPUT

    def __init__(self, path: str, problem: str) -> None:
        self.path, self.problem = path, problem
        super().__init__(f"{path}: {problem}")


@dataclass(frozen=True)
class Resolved:
    links: tuple[Link, ...]
    dpus: tuple[Dpu, ...]
    buffers: tuple[Buffer, ...]
    processes: tuple[Process, ...]
    chains: tuple[Chain, ...]
    events: tuple[Event, ...]


def resolve(spec: SystemSpec, base: Path) -> Resolved:
    """`base`: the system file's folder, where a `samples:` file is looked for."""
    links = _links(spec.links)
    dpu_links = _dpu_links(spec, links)
    buffer_links = _buffer_links(spec, links)
    ports = _processes(spec, buffer_links)
    varying = _varying(spec, base)
    writers = _writers(spec, ports)
    _reach(spec, dpu_links, buffer_links, writers, ports)
    writer_port = _link_ports(spec, links, buffer_links, writers)
    minor = _minor_cycles(spec)
    _links_opened(spec, buffer_links, writers, ports, writer_port)
    order = _orders(spec)
    priority = _priorities(spec, order)
    by_name = {p.name: p for p in spec.processes}
    chains = _chains(spec, by_name)
    events = _events(spec)
    _reference(spec)
    dpus = tuple(Dpu(d.id, d.host, d.cpu, d.compute, d.executive, d.speed, minor[d.id], dpu_links[d.id])
                 for d in spec.dpus)
    buffers = tuple(Buffer(b.id, b.name, b.bytes, buffer_links[b.id].id, by_name[writers[b.id]].id)
                    for b in spec.buffers)
    processes = charges(links, dpus, buffers, tuple(
        Process(p.id, p.name, p.dpu, order[p.id], p.period_us, _compute_us(p, varying), p.sync,
                ports[p.id][0], ports[p.id][2], ports[p.id][1], varying.get(p.id), priority[p.id],
                p.event or "", (p.queue or 1) if p.sync == "event" else 0, tuple(p.emits),
                code=Code(p.compute.library, p.compute.function) if p.compute else None)
        for p in spec.processes))
    _charged_tasking(spec, processes)
    _code_reads_what_comes(links, buffers, processes)
    return Resolved(links=links, dpus=dpus, buffers=buffers, processes=processes, chains=chains,
                    events=events)


def _code_reads_what_comes(links: tuple[Link, ...], buffers: tuple[Buffer, ...],
                           processes: tuple[Process, ...]) -> None:
    """Real code reads the bytes a DPU keeps as a message comes; a link that holds versions back
    (latency, jitter, bandwidth) does not keep their bytes yet (dpu/config.c refuses it too)."""
    link, buffer = {k.id: k for k in links}, {b.id: b for b in buffers}
    for p in processes:
        for b in (buffer[i] for i in (p.inputs if p.code is not None else ())):
            if link[b.link].holds:
                raise Invalid(f"processes.{p.name}.compute", f"real code cannot read {b.name} through link "
                              f"{link[b.link].name}'s emulated latency or bandwidth yet")


def _charged_tasking(spec: SystemSpec, processes: tuple[Process, ...]) -> None:
    """The link costs are charged by the cyclic executive only (dpu/process.c)."""
    tasking = {d.id for d in spec.dpus if d.executive == "threads"}
    for p in processes:
        if p.dpu in tasking and p.charge.us > 0:
            raise Invalid(f"dpus.{p.dpu}.executive",
                          f"the tasking executive charges no link costs yet (process {p.name} would "
                          "pay its links' per_message_us, per_byte_ns, push_byte_ns or remote_read_us): "
                          "use `cyclic`, or links without costs")


def _unique(items: Sequence[Any], section: str, attr: str) -> None:
    seen: dict[Any, int] = {}
    for i, item in enumerate(items):
        value = getattr(item, attr)
        if value in seen:
            also = f"{section}[{seen[value]}]"
            raise Invalid(f"{section}[{i}].{attr}", f"duplicate {attr} {show(value)} (also {also})")
        seen[value] = i


def _links(specs: list[LinkSpec] | None) -> tuple[Link, ...]:
    if specs is None:
        specs = [LinkSpec(name=DEFAULT_LINK, url=contract.DEFAULT_URL)]
    _unique(specs, "links", "name")
    if all(s.url == "local" for s in specs):
        raise Invalid("links", "needs at least one udpm:// link: the host reaches the DPUs over it")
    return tuple(Link(i + 1, s.name, s.url, s.figure("bandwidth_mbps"), s.latency_us, s.jitter_us, s.jitter,
                      s.loss_pct, None if (b := s.loss_burst) is None else LossBurst(b.enter_pct, b.leave_pct,
                                                                                     b.loss_pct),
                      **{cost: s.figure(cost) or 0.0 for cost in COSTS},
                      queue_us=(s.queue_us or QUEUE_US) if s.figure("bandwidth_mbps") else 0)
                 for i, s in enumerate(specs))


def _dpu_links(spec: SystemSpec, links: tuple[Link, ...]) -> dict[int, tuple[int, ...]]:
    _unique(spec.dpus, "dpus", "id")
    ids = {link.name: link.id for link in links}
    out: dict[int, tuple[int, ...]] = {}
    for d in spec.dpus:
        names = d.links if d.links is not None else list(ids)
        for j, name in enumerate(names):
            if name not in ids:
                raise Invalid(f"dpus.{d.id}.links[{j}]",
                              f"no link named {show(name)}; links: {', '.join(ids)}")
            if names.index(name) != j:
                raise Invalid(f"dpus.{d.id}.links[{j}]", f"link {show(name)} is listed twice")
        out[d.id] = tuple(ids[n] for n in names)
    return out


def _buffer_links(spec: SystemSpec, links: tuple[Link, ...]) -> dict[int, Link]:
    _unique(spec.buffers, "buffers", "id")
    _unique(spec.buffers, "buffers", "name")
    by_name = {link.name: link for link in links}
    default = control_link(links)
    assert default is not None, "_links refuses a system without a udpm link"
    out: dict[int, Link] = {}
    for b in spec.buffers:
        if b.link is not None and b.link not in by_name:
            raise Invalid(f"buffers.{b.name}.link",
                          f"no link named {show(b.link)}; links: {', '.join(by_name)}")
        out[b.id] = by_name[b.link] if b.link is not None else default
    return out


# Per process: (input buffer ids, output buffer ids, required buffer ids).
Ports = dict[int, tuple[tuple[int, ...], tuple[int, ...], tuple[int, ...]]]


def _processes(spec: SystemSpec, buffer_links: dict[int, Link]) -> Ports:
    _unique(spec.processes, "processes", "id")
    _unique(spec.processes, "processes", "name")
    dpu_ids = [d.id for d in spec.dpus]
    ports: Ports = {}
    for p in spec.processes:
        path = f"processes.{p.name}"
        if p.dpu not in dpu_ids:
            raise Invalid(f"{path}.dpu", f"no DPU with id {p.dpu}; DPUs: {', '.join(map(str, dpu_ids))}")
        inputs = _buffer_refs(spec, p, "inputs", p.inputs)
        outputs = _buffer_refs(spec, p, "outputs", p.outputs)
        for j, b in enumerate(inputs):
            if b in outputs:
                raise Invalid(f"{path}.inputs[{j}]", f"reads its own output buffer {show(_bname(spec, b))}")
        ports[p.id] = (inputs, outputs, _required(spec, p, inputs))
    return ports


def _compute_us(p: ProcessSpec, varying: dict[int, Varying]) -> int:
    """What the schedule counts on: the constant, or the mean of what will be drawn."""
    return p.compute_us if isinstance(p.compute_us, int) else round(varying[p.id].mean_us)


def _varying(spec: SystemSpec, base: Path) -> dict[int, Varying]:
    """The compute times that vary, by process id; every compute time's worst case is checked
    against its period (a worst case of 100 periods is a units mistake)."""
    out: dict[int, Varying] = {}
    for p in spec.processes:
        path = f"processes.{p.name}.compute_us"
        worst: float
        if isinstance(p.compute_us, ComputeSpec):
            try:
                out[p.id] = varying(p.compute_us, base)
            except ComputeError as e:
                raise Invalid(f"{path}.{e.key}", e.problem) from None
            worst, where = out[p.id].max_us, f"{path}.{'samples' if p.compute_us.samples else 'max'}"
        else:
            worst, where = p.compute_us, path
        if worst > ABSURD_COMPUTE_PERIODS * p.period_us:
            raise Invalid(where, f"{worst:g} us is more than {ABSURD_COMPUTE_PERIODS} "
                          f"periods ({p.period_us} us): absurd; both are in microseconds")
    return out


def _bname(spec: SystemSpec, buffer_id: int) -> str:
    return next(b.name for b in spec.buffers if b.id == buffer_id)


def _buffer_refs(spec: SystemSpec, p: ProcessSpec, key: str, refs: Sequence[int | str]) -> tuple[int, ...]:
    path = f"processes.{p.name}.{key}"
    if len(refs) > contract.MAX_IO:
        raise Invalid(path, f"{len(refs)} {key}; at most {contract.MAX_IO} per process")
    out: list[int] = []
    for j, ref in enumerate(refs):
        found = _find_buffer(spec.buffers, ref)
        if found is None:
            raise Invalid(f"{path}[{j}]", f"no buffer with id {ref}" if isinstance(ref, int) else
                          f"no buffer named {show(ref)}; "
                          + (did_you_mean(ref, [b.name for b in spec.buffers])
                             or f"buffers: {', '.join(b.name for b in spec.buffers)}"))
        if found.id in out:
            raise Invalid(f"{path}[{j}]", f"buffer {show(found.name)} is listed twice")
        out.append(found.id)
    return tuple(out)


def _find_buffer(buffers: list[BufferSpec], ref: int | str) -> BufferSpec | None:
    return next((b for b in buffers if (b.id if isinstance(ref, int) else b.name) == ref), None)


def _required(spec: SystemSpec, p: ProcessSpec, inputs: tuple[int, ...]) -> tuple[int, ...]:
    path = f"processes.{p.name}"
    if p.sync != "data":
        if p.required is not None:
            raise Invalid(f"{path}.required", "only a `sync: data` process waits for required inputs; "
                          "remove `required` or set `sync: data`")
        return ()
    required: list[int] = []
    for j, ref in enumerate(p.required if p.required is not None else inputs):
        found = _find_buffer(spec.buffers, ref)
        if found is None or found.id not in inputs:
            raise Invalid(f"{path}.required[{j}]", f"{show(ref)} is not one of the process's inputs")
        if found.id in required:
            raise Invalid(f"{path}.required[{j}]", f"buffer {show(found.name)} is listed twice")
        required.append(found.id)
    if not required:
        raise Invalid(f"{path}.sync", "a `sync: data` process needs at least one required input; "
                      "give it inputs or use `sync: periodic`")
    return tuple(required)


def _writers(spec: SystemSpec, ports: Ports) -> dict[int, str]:
    out: dict[int, str] = {}
    for b in spec.buffers:
        names = [p.name for p in spec.processes if b.id in ports[p.id][1]]
        if not names:
            raise Invalid(f"buffers.{b.name}", "no process writes it; list it in one process's outputs")
        if len(names) > 1:
            raise Invalid(f"buffers.{b.name}", f"written by both {show(names[0])} and {show(names[1])}; "
                          "a buffer has exactly one writer")
        out[b.id] = names[0]
    return out


def _link_ports(spec: SystemSpec, links: tuple[Link, ...], buffer_links: dict[int, Link],
                writers: dict[int, str]) -> dict[tuple[int, int], int]:
    """Each writer's buffers get a port of their own next to their link's (host/sysfile/link.py):
    the ports must exist and no two links may share one."""
    control = control_link(links)
    for link in links:
        if not link.local:
            try:
                parse_url(link.url)
                if link is control:  # its record URL too: the DPUs' heartbeats and timing go there
                    record_url(link.url)
            except ValueError as exc:
                raise Invalid(f"links.{link.name}.url", str(exc)) from None
    ids = {p.name: p.id for p in spec.processes}
    ports = writer_ports(links, ((buffer_links[b.id].id, ids[writers[b.id]]) for b in spec.buffers))
    clash = port_clash(links, ports)
    if clash is not None:
        raise Invalid(f"links.{clash[0].name}.url", clash[1])
    return ports


def _links_opened(spec: SystemSpec, buffer_links: dict[int, Link], writers: dict[int, str],
                  ports: Ports, writer_port: dict[tuple[int, int], int]) -> None:
    """A DPU opens a link per writer it reads or is (its group and port), and the control URL
    when it awaits or emits events (dpu/event.c): at most contract.MAX_LINKS."""
    ids = {p.name: p.id for p in spec.processes}
    for d in spec.dpus:
        mine = [p for p in spec.processes if p.dpu == d.id]
        used = {writer_port[buffer_links[b].id, ids[writers[b]]] for p in mine
                for b in ports[p.id][0] + ports[p.id][1] if not buffer_links[b].local}  # fmt: skip
        events = any(p.sync == "event" or p.emits for p in mine)
        if len(used) + events > contract.MAX_LINKS:
            said = " and the control URL for its events" if events else ""
            raise Invalid(f"dpus.{d.id}", f"its processes read or write the buffers of {len(used)} writers "
                          f"(a group and port each){said}; a DPU opens at most {contract.MAX_LINKS}: "
                          "spread its processes over more DPUs")


def _reach(spec: SystemSpec, dpu_links: dict[int, tuple[int, ...]],
           buffer_links: dict[int, Link], writers: dict[int, str], ports: Ports) -> None:
    dpu_of = {p.name: p.dpu for p in spec.processes}
    for p in spec.processes:
        for key, buffers in (("inputs", ports[p.id][0]), ("outputs", ports[p.id][1])):
            for j, b in enumerate(buffers):
                link, name, path = buffer_links[b], _bname(spec, b), f"processes.{p.name}.{key}[{j}]"
                if link.id not in dpu_links[p.dpu]:
                    raise Invalid(path, f"DPU {p.dpu} cannot reach link {show(link.name)} of buffer "
                                  f"{show(name)}; add it to dpus.{p.dpu}.links")
                writer_dpu = dpu_of[writers[b]]
                if link.local and writer_dpu != p.dpu:
                    raise Invalid(path, f"buffer {show(name)} is on local link {show(link.name)} inside "
                                  f"DPU {writer_dpu} (its writer {show(writers[b])}) but {show(p.name)} runs "
                                  f"on DPU {p.dpu}; a local link reaches only inside one DPU")


def _minor_cycles(spec: SystemSpec) -> dict[int, int]:
    critical = min(p.period_us for p in spec.processes)
    out: dict[int, int] = {}
    for d in spec.dpus:
        mine = [p for p in spec.processes if p.dpu == d.id]
        if len(mine) > contract.MAX_PROCESSES:
            raise Invalid(f"dpus.{d.id}", f"{len(mine)} processes; at most {contract.MAX_PROCESSES} per DPU")
        periods = sorted({p.period_us for p in mine}) or [critical]
        if d.minor_cycle_us is None:
            minor = math.gcd(*periods)
            if minor < contract.MIN_PERIOD_US and d.executive == "cyclic":
                listed = ", ".join(map(str, periods))
                raise Invalid(f"dpus.{d.id}", f"minor cycle {minor} us (the gcd of its periods {listed} us) "
                              f"is below {contract.MIN_PERIOD_US} us; give the periods a larger common "
                              "divisor or set minor_cycle_us")
        else:
            minor = d.minor_cycle_us
            if minor < contract.MIN_PERIOD_US:
                raise Invalid(f"dpus.{d.id}.minor_cycle_us",
                              f"must be at least {contract.MIN_PERIOD_US} us, got {minor}")
            for p in mine if d.executive == "cyclic" else []:
                if p.period_us % minor:
                    raise Invalid(f"processes.{p.name}.period_us", f"{p.period_us} us is not a multiple of "
                                  f"DPU {d.id}'s minor cycle ({minor} us)")
        out[d.id] = minor
    return out


def _orders(spec: SystemSpec) -> dict[int, int]:
    out: dict[int, int] = {}
    for d in spec.dpus:
        mine = [p for p in spec.processes if p.dpu == d.id]
        taken: dict[int, str] = {}
        for p in mine:
            if p.order is not None and p.order in taken:
                raise Invalid(f"processes.{p.name}.order",
                              f"order {p.order} is already taken on DPU {d.id} by {show(taken[p.order])}")
            if p.order is not None:
                taken[p.order] = p.name
        # Explicit orders place a process (first among equals); the others keep their place in the file.
        ranked = sorted(enumerate(mine),
                        key=lambda ip: (ip[1].order or ip[0] + 1, ip[1].order is None, ip[0]))
        out.update({p.id: rank + 1 for rank, (_, p) in enumerate(ranked)})
    return out


def _priorities(spec: SystemSpec, order: dict[int, int]) -> dict[int, int]:
    """The tasking executive's priorities: given for every process of a DPU or for none,
    then rate-monotonic (the shorter period first; equal periods by order)."""
    out: dict[int, int] = {}
    for d in spec.dpus:
        mine = [p for p in spec.processes if p.dpu == d.id]
        given = [p for p in mine if p.priority is not None]
        if d.executive != "cyclic" and (coded := next((p for p in mine if p.compute), None)):
            raise Invalid(f"processes.{coded.name}.compute", f"DPU {d.id} runs executive: {d.executive}; "
                          "real code runs on the cyclic executive only")
        if d.executive == "cyclic":
            if given:
                raise Invalid(f"processes.{given[0].name}.priority", f"DPU {d.id} runs the cyclic executive, "
                              "which runs processes by order; priority needs executive: threads")
            out.update({p.id: 0 for p in mine})
            continue
        if given and len(given) < len(mine):
            bare = next(p for p in mine if p.priority is None)
            raise Invalid(f"processes.{bare.name}.priority", f"give every process of DPU {d.id} a priority, "
                          "or none (rate-monotonic)")
        taken: dict[int, str] = {}
        for p in given:
            if p.priority in taken:
                raise Invalid(f"processes.{p.name}.priority", f"priority {p.priority} is already taken "
                              f"on DPU {d.id} by {show(taken[p.priority])}")
            taken[p.priority] = p.name
            out[p.id] = p.priority
        if not given:
            ranked = sorted(mine, key=lambda p: (p.period_us, order[p.id]))
            out.update({p.id: contract.MAX_PRIORITY - rank for rank, p in enumerate(ranked)})
    return out


def _chains(spec: SystemSpec, by_name: dict[str, ProcessSpec]) -> tuple[Chain, ...]:
    chains: list[Chain] = []
    for i, c in enumerate(spec.chains):
        name = c.name or "->".join(c.processes)
        path = f"chains.{c.name}" if c.name else f"chains[{i}]"
        item = f"{path}.processes" if c.name else path
        if any(other.name == name for other in chains):
            raise Invalid(path, f"duplicate chain name {show(name)}")
        if len(c.processes) < 2:
            raise Invalid(path, "a chain needs at least 2 processes")
        for j, pname in enumerate(c.processes):
            if pname not in by_name:
                raise Invalid(f"{item}[{j}]", f"no process named {show(pname)}; "
                              + (did_you_mean(pname, list(by_name)) or f"processes: {', '.join(by_name)}"))
            if c.processes.index(pname) != j:
                raise Invalid(f"{item}[{j}]", f"process {show(pname)} is listed twice")
            if j and not set(_outputs(spec, c.processes[j - 1])) & set(_inputs(spec, pname)):
                before = show(c.processes[j - 1])
                raise Invalid(f"{item}[{j}]", f"{show(pname)} reads no buffer that {before} writes")
        chains.append(Chain(name, tuple(by_name[n].id for n in c.processes)))
    return tuple(chains)


def _events(spec: SystemSpec) -> tuple[Event, ...]:
    """Every awaited event has a source (the host, a generator or an emitting process), and
    no DPU awaits, emits or generates more distinct events than it can subscribe to."""
    _unique(spec.events, "events", "name")
    dpu_ids = [d.id for d in spec.dpus]
    for e in spec.events:
        if e.dpu is not None and e.dpu not in dpu_ids:
            known = ", ".join(map(str, dpu_ids))
            raise Invalid(f"events.{e.name}.dpu", f"no DPU with id {e.dpu}; DPUs: {known}")
    sources = {e.name for e in spec.events} | {n for p in spec.processes for n in p.emits}
    names: dict[int, set[str]] = {d: set() for d in dpu_ids}
    for p in spec.processes:
        path = f"processes.{p.name}"
        if p.sync == "event" and p.event is None:
            raise Invalid(f"{path}.event", "a `sync: event` process names the event it awaits")
        if p.sync != "event":
            for key in ("event", "queue"):
                if getattr(p, key) is not None:
                    raise Invalid(f"{path}.{key}", f"only a `sync: event` process has {key}; set "
                                  "`sync: event` or remove it")
        if p.event is not None and p.event not in sources:
            raise Invalid(f"{path}.event", f"event {show(p.event)} is emitted by no process and "
                          "generated by no `events:` entry; add one (kind: host to send it with "
                          "`skel event`)")
        if p.event in p.emits:
            raise Invalid(f"{path}.emits", f"it emits the event {show(p.event)} it awaits: it would "
                          "run for ever on its own events")
        for j, n in enumerate(p.emits):
            if n in p.emits[:j]:
                raise Invalid(f"{path}.emits[{j}]", f"event {show(n)} is listed twice")
        names[p.dpu] |= set(p.emits) | ({p.event} if p.event else set())
    for e in spec.events:
        if e.dpu is not None:
            names[e.dpu].add(e.name)
    for d, used in names.items():
        if len(used) > contract.MAX_EVENTS:
            raise Invalid(f"dpus.{d}", f"awaits, emits or generates {len(used)} distinct events; at "
                          f"most {contract.MAX_EVENTS} per DPU")
    return tuple(Event(e.name, e.kind, e.dpu or 0, e.period_us or 0, e.jitter_us or 0, e.rate_hz or 0.0,
                       e.count or 0, e.spacing_us or 0) for e in spec.events)


def _reference(spec: SystemSpec) -> None:
    ids = {d.id for d in spec.dpus}
    for dpu in spec.reference.dpus if spec.reference else {}:
        if dpu not in ids:
            raise Invalid(f"reference.dpus.{dpu}", f"no DPU with id {dpu}")
    return True


def _inputs(spec: SystemSpec, name: str) -> list[int]:
    p = next(p for p in spec.processes if p.name == name)
    return [b.id for ref in p.inputs if (b := _find_buffer(spec.buffers, ref)) is not None]


def _outputs(spec: SystemSpec, name: str) -> list[int]:
    p = next(p for p in spec.processes if p.name == name)
    return [b.id for ref in p.outputs if (b := _find_buffer(spec.buffers, ref)) is not None]
