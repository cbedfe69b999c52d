"""The typed model of a system: the frozen records every layer reads, whoever made them.

The loader (host/sysfile/system.py) builds a System from a system file; the prediction
(host/theory/) reads it; the DPUs are sent it as a config_t (host/live/wire.py). Nothing
here validates or parses: pydantic is the file's schema only (host/sysfile/schema.py).
At the bottom of host/: every package above may import it, and so may analysis/.
"""

from __future__ import annotations

import dataclasses
import functools
import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

import skelmsg
from skelmsg.contract import BUFFER_HEADER_BYTES, WIRE_LCM_HEADER_BYTES, WIRE_UDP_IP_BYTES


@dataclass(frozen=True)
class Link:
    id: int                 # position in the file, from 1
    name: str
    url: str                # "local" or an udpm:// URL
    bandwidth_mbps: float | None = None
    # The transport the reading DPUs emulate (schema.LinkSpec's last block)
    latency_us: int = 0
    jitter_us: int = 0
    jitter: str = "uniform"            # uniform | normal
    loss_pct: float = 0.0              # the good state's when bursty
    burst: LossBurst | None = None
    # its CPU costs (the schema's LinkSpec, a preset's filled in), charged by the DPUs: charges()
    per_message_us: float = 0.0
    per_byte_ns: float = 0.0
    push_byte_ns: float = 0.0
    remote_read_us: float = 0.0
    # with bandwidth_mbps: the longest a message waits for the transmitter before it is dropped
    queue_us: int = 0

    @property
    def local(self) -> bool:
        return self.url == "local"

    @property
    def holds(self) -> bool:
        """Whether its reading DPUs hold versions back (latency, jitter, or a turn on the bus)."""
        return bool(self.latency_us or self.jitter_us or self.bandwidth_mbps)

    def message_bytes(self, buffer: Buffer) -> int:
        """One message of BUFFER as this link carries it: the payload in memory (a `local` link,
        which has no bandwidth), else on the wire."""
        return buffer.bytes if self.local else buffer.wire_bytes

    def wire_us(self, buffer: Buffer) -> float:
        """The time one message of BUFFER takes on the link's transmitter (0: no bandwidth given)."""
        return 8 * self.message_bytes(buffer) / self.bandwidth_mbps if self.bandwidth_mbps else 0.0

    @property
    def costs(self) -> bool:
        return any((self.per_message_us, self.per_byte_ns, self.push_byte_ns, self.remote_read_us))

    @property
    def delay_us(self) -> tuple[float, float, float]:
        """The least, mean and most delay of a buffer on it (a normal jitter is cut at 3 sigma)."""
        spread = self.jitter_us * (3 if self.jitter == "normal" else 1)
        return max(0.0, self.latency_us - spread), float(self.latency_us), float(self.latency_us + spread)

    @property
    def mean_loss_pct(self) -> float:
        """The long-run share of buffers lost: the bad state's loss for the share of time it is bad."""
        b = self.burst
        if b is None or b.enter_pct == 0:
            return self.loss_pct
        bad = b.enter_pct / (b.enter_pct + b.leave_pct)
        return (1 - bad) * self.loss_pct + bad * b.loss_pct


@dataclass(frozen=True)
class LossBurst:
    enter_pct: float        # per version: good -> bad
    leave_pct: float        # per version: bad -> good
    loss_pct: float         # lost in the bad state


@dataclass(frozen=True)
class Dpu:
    id: int
    host: str
    cpu: int | None
    compute: str            # sleep | wall | cpu | work
    executive: str          # cyclic | threads
    speed: float
    minor_cycle_us: int     # resolved: given, or the gcd of its processes' periods
    links: tuple[int, ...]  # link ids it can reach


@dataclass(frozen=True)
class Buffer:
    id: int
    name: str
    bytes: int
    link: int               # link id
    writer: int             # process id

    @property
    def channel(self) -> str:
        return f"SKEL_BUF_{self.name}"

    @property
    def wire_bytes(self) -> int:
        """One message of it on an IP link: buffer_t's bytes before the payload (the contract's
        BUFFER_HEADER_BYTES), the payload, LCM's short-message header (magic, sequence, the
        channel name and its NUL), UDP and IPv4 headers."""
        return (BUFFER_HEADER_BYTES + self.bytes + WIRE_LCM_HEADER_BYTES + len(self.channel) + 1
                + WIRE_UDP_IP_BYTES)


@dataclass(frozen=True)
class Varying:
    """A compute time drawn each cycle from `quantiles_us`: its quantile function at evenly
    spaced probabilities from 0 to 1, linear between points (host/sysfile/compute.py makes it)."""

    kind: str                         # uniform | normal | lognormal | exponential | samples
    quantiles_us: tuple[float, ...]
    # As the system file wrote it (for dump_yaml); the table alone says what is drawn, and a
    # dict would make the frozen records unhashable.
    given: dict[str, Any] = field(compare=False)

    @property
    def mean_us(self) -> float:
        q = self.quantiles_us
        return sum(a + b for a, b in itertools.pairwise(q)) / (2 * (len(q) - 1))

    @property
    def min_us(self) -> float:
        return self.quantiles_us[0]

    @property
    def max_us(self) -> float:
        return self.quantiles_us[-1]


@dataclass(frozen=True)
class Charge:
    """The CPU a process's DPU charges it per cycle for its links' costs, in us (charges())."""

    in_us: float = 0.0          # comm_in: its remote reads, and the messages it pays for, on average
    in_worst_us: float = 0.0    # ... with the most messages one cycle can find (a slower reader)
    in_best_us: float = 0.0     # ... and the fewest
    out_us: float = 0.0         # comm_out: what it publishes

    @property
    def us(self) -> float:
        return self.in_us + self.out_us


@dataclass(frozen=True)
class Code:
    """Real code a process runs in place of its emulated computation (include/skel_step.h)."""
    library: str            # NAME: libNAME.so in each DPU's --lib-dir
    function: str


@dataclass(frozen=True)
class Process:
    id: int
    name: str
    dpu: int
    order: int              # 1.. within its DPU's minor cycle
    period_us: int
    compute_us: int         # the constant, or the mean of `varying` (rounded): the schedule's figure
    sync: str               # periodic | data | event
    inputs: tuple[int, ...]     # buffer ids
    required: tuple[int, ...]   # buffer ids a data-synchronised cycle waits for
    outputs: tuple[int, ...]
    varying: Varying | None = None  # how compute varies (None: compute_us every cycle)
    priority: int = 0       # on the tasking executive: 1..MAX_PRIORITY, higher first; 0 on cyclic
    event: str = ""         # sync: event: the event it awaits ...
    queue: int = 0          # ... and how many may wait for it (1..MAX_QUEUE)
    emits: tuple[str, ...] = ()  # events it fires at the end of each cycle
    charge: Charge = Charge()   # its links' costs per cycle (charges())
    code: Code | None = None     # real code in place of the emulated computation; compute_us stays the
                                 # prediction's assumption

    @property
    def worst_compute_us(self) -> float:
        return self.varying.max_us if self.varying else self.compute_us

    @property
    def best_compute_us(self) -> float:
        return self.varying.min_us if self.varying else self.compute_us


@dataclass(frozen=True)
class Event:
    """A source of a named event: the host, or a generator on DPU `dpu`."""
    name: str
    kind: str               # host | periodic | poisson | bursts
    dpu: int = 0            # the generating DPU; 0: the host
    period_us: int = 0
    jitter_us: int = 0
    rate_hz: float = 0.0
    count: int = 0
    spacing_us: int = 0

    @property
    def rate(self) -> float:
        """Mean events per second (0: the host's, unknown)."""
        if self.kind == "poisson":
            return self.rate_hz
        per_period = self.count if self.kind == "bursts" else 1
        return per_period * 1e6 / self.period_us if self.period_us else 0.0


@dataclass(frozen=True)
class Chain:
    name: str
    processes: tuple[int, ...]  # process ids, head first


@dataclass(frozen=True)
class RunRules:
    """The file's `run:` section (schema.Run validates it): the run's length, warm-up, lockout
    rule and when to stop early. cycles counts the critical period."""

    cycles: int | None
    duration_s: float | None
    warmup_cycles: int
    lockout_cycles: int
    stop_on: tuple[str, ...]
    late_pct: int
    too_late_pct: int
    seed: int
    network: str = "kernel"


@dataclass(frozen=True)
class ReferenceDpu:
    """One DPU's row of a published measurement (e.g. the paper's Table 1)."""

    compute_pct: float
    communicate_pct: float
    wait_pct: float
    cycle_ms: float | None = None            # measured cycle
    modeled_cycle_ms: float | None = None


@dataclass(frozen=True)
class Reference:
    """Published results to compare a run with (`skel run --compare-paper`); not sent to DPUs."""

    source: str
    dpus: dict[int, ReferenceDpu] = field(default_factory=dict)


@dataclass(frozen=True)
class Bus:
    """A bandwidth-limited link's transmitter as its reading DPUs emulate it (dpu/buffers.c):
    every message on the link takes its bytes' time on the wire (Link.wire_us), one after
    another in the order sent, and one that would wait longer than the link's queue_us is
    dropped. The figures take each writer at its most, one message a period."""

    utilization: float                  # of the bandwidth (1: all of it)
    waits_us: dict[int, float] = field(compare=False)  # per buffer: the longest a message waits
    # the long-run share of the offered bytes the full queue drops (over 1: 1 - 1/U); of the
    # messages, more of the small or of the large, as they come
    dropped_pct: float = 0.0

    @property
    def saturated(self) -> bool:
        return self.utilization > 1

    @property
    def most_wait_us(self) -> float:
        return max(self.waits_us.values(), default=0.0)


def bus_of(link: Link, flows: Sequence[tuple[int, float, float]]) -> Bus:
    """LINK's transmitter for FLOWS, each (buffer id, its writer's period, its wire time) in us.
    At or over all of the bandwidth, the queue fills: a message waits its whole queue_us. Under
    it, a FIFO queue is longest when every writer sends at once, and a message waits longest
    behind all the others sent then: the work sent by any instant after is less than the time
    gone by it (U < 1), so the queue never grows past that. Each writer sends once a period, a
    period apart: one whose sends come closer (its response varies) can make a message wait
    longer than this."""
    utilization = sum(c / t for _, t, c in flows)
    if utilization >= 1 - 1e-12:
        return Bus(utilization, {b: float(link.queue_us) for b, _, _ in flows},
                   100 * max(0.0, 1 - 1 / utilization))
    together = sum(c for _, _, c in flows)
    return Bus(utilization, {b: min(float(link.queue_us), together - own) for b, _, own in flows})


def control_link(links: Sequence[Link]) -> Link | None:
    """The first udpm link: its URL is the control URL (None: every link is local)."""
    return next((link for link in links if not link.local), None)


@dataclass(frozen=True)
class System:
    """A validated system file: what the host broadcasts, runs and reports on."""
    name: str
    path: Path
    source_text: str                # the YAML used: the file, or its re-dump after overrides
    links: tuple[Link, ...]
    dpus: tuple[Dpu, ...]
    buffers: tuple[Buffer, ...]
    processes: tuple[Process, ...]
    run: RunRules
    chains: tuple[Chain, ...]
    reference: Reference | None
    events: tuple[Event, ...] = ()
    overrides: tuple[str, ...] = ()
    document: dict[str, Any] = field(default_factory=dict, repr=False, compare=False)
    # What the link rules (host/sysfile/link.py) give: (link id, writer process id) -> the port
    # its buffers travel on, and each buffer's URL ("" on a local link).
    writer_ports: dict[tuple[int, int], int] = field(default_factory=dict, repr=False, compare=False)
    buffer_urls: dict[int, str] = field(default_factory=dict, repr=False, compare=False)

    # Lookups by id (an int) or name (a str) raise KeyError: after validation a missing one is
    # the caller's bug.
    def link(self, key: int | str) -> Link:
        return _lookup(self._index["link"], key, "link")

    def dpu(self, dpu_id: int) -> Dpu:
        return _lookup(self._index["DPU"], dpu_id, "DPU")

    def buffer(self, key: int | str) -> Buffer:
        return _lookup(self._index["buffer"], key, "buffer")

    def process(self, key: int | str) -> Process:
        return _lookup(self._index["process"], key, "process")

    def find_process(self, key: int | str) -> Process | None:
        """The process, or None: a config read from a log may name one it does not hold."""
        return self._index["process"].get(key)

    def find_buffer(self, key: int | str) -> Buffer | None:
        return self._index["buffer"].get(key)

    @functools.cached_property
    def _index(self) -> dict[str, dict[int | str, Any]]:
        """Each kind of record by id and by name (the first of a name, as a search would find)."""
        index: dict[str, dict[int | str, Any]] = {}
        for noun, items in (("link", self.links), ("DPU", self.dpus), ("buffer", self.buffers),
                            ("process", self.processes)):
            by: dict[int | str, Any] = index.setdefault(noun, {})
            for item in items:
                by.setdefault(item.id, item)
                if hasattr(item, "name"):
                    by.setdefault(item.name, item)
        return index

    def processes_on(self, dpu_id: int) -> list[Process]:
        """The DPU's processes in the order its minor cycle runs them."""
        return sorted((p for p in self.processes if p.dpu == dpu_id), key=lambda p: p.order)

    def readers(self, buffer_id: int) -> list[Process]:
        return [p for p in self.processes if buffer_id in p.inputs]

    def buffer_url(self, key: int | str) -> str:
        """The URL a buffer travels on: its writer's group and port on its link; "" on a local link."""
        return self.buffer_urls[self.buffer(key).id]

    @functools.cached_property
    def buses(self) -> dict[int, Bus]:
        """Each bandwidth-limited link's transmitter, by link id."""
        return {k.id: bus_of(k, [(b.id, self.process(b.writer).period_us, k.wire_us(b))
                                 for b in self.buffers if b.link == k.id and self.find_process(b.writer)])
                for k in self.links if k.bandwidth_mbps}

    def transport_us(self, buffer_id: int) -> tuple[float, float, float]:
        """The least, mean and most delay a buffer's link emulates: its latency and jitter
        (Link.delay_us), and on a bandwidth-limited link its own time on the wire, plus at most
        its longest wait for the transmitter (on average, the whole queue when saturated)."""
        b = self.buffer(buffer_id)
        link = self.link(b.link)
        least, mean, most = link.delay_us
        bus = self.buses.get(link.id)
        if bus is None:
            return least, mean, most
        wire, wait = link.wire_us(b), bus.waits_us.get(b.id, 0.0)
        return least + wire, mean + wire + (wait if bus.saturated else 0.0), most + wire + wait

    def lost_pct(self, link_id: int) -> float:
        """The long-run share of a link's messages a reading DPU never sees: the link's loss, and
        what a saturated link's full queue drops before it (Bus.dropped_pct: of the bytes)."""
        link = self.link(link_id)
        bus = self.buses.get(link.id)
        if bus is None or not bus.dropped_pct:
            return link.mean_loss_pct
        return 100 * (1 - (1 - bus.dropped_pct / 100) * (1 - link.mean_loss_pct / 100))

    @property
    def default_link(self) -> Link:
        """The first udpm link: buffers without a `link:` use it, and so does control traffic."""
        found = control_link(self.links)
        assert found is not None, "rules._links refuses a system without a udpm link"
        return found

    @property
    def critical_period_us(self) -> int:
        """The shortest period of the clock-driven processes (`run.cycles` counts these): an
        event process's period only bounds how often it may run."""
        clocked = [p.period_us for p in self.processes if p.sync != "event"]
        return min(clocked or [p.period_us for p in self.processes])

    def static_load(self, worst: bool = False) -> dict[int, float]:
        """Per DPU, the fraction of its time its processes compute: Σ compute/period / speed,
        with each varying compute at its mean, or at its maximum when `worst`."""
        def compute(p: Process) -> float:
            return p.worst_compute_us if worst else p.compute_us
        return {
            d.id: sum(compute(p) / p.period_us for p in self.processes if p.dpu == d.id) / d.speed
            for d in self.dpus
        }

    def run_duration_ns(self, cycles: int | None = None, duration_s: float | None = None) -> int:
        """The run's length; arguments (the command line) beat the file's `run:` section.
        Cycles count the critical (shortest) period and include the warm-up."""
        if cycles is not None and duration_s is not None:
            raise ValueError("give cycles or a duration, not both")
        if cycles is None and duration_s is None:
            cycles, duration_s = self.run.cycles, self.run.duration_s
        if cycles is not None:
            if cycles < 1:
                raise ValueError(f"cycles must be at least 1, got {cycles}")
            return cycles * self.critical_period_us * 1000
        if duration_s is None or not duration_s > 0:
            raise ValueError(f"duration must be positive, got {duration_s}")
        return round(duration_s * 1e9)


def _lookup(index: dict[int | str, Any], key: int | str, noun: str) -> Any:
    try:
        return index[key]
    except KeyError:
        raise KeyError(f"no {noun} {key!r}") from None



# --- a prediction as the analysis lays it beside a run ---------------------------------------
@dataclass(frozen=True)
class ExpectedDpu:
    id: int
    compute_pct: float | None       # None: it follows from how often the host sends an event
    communicate_pct: float | None = None  # its links' charged costs (None: unknown, or a log before them)


@dataclass(frozen=True)
class ExpectedProcess:
    name: str
    response_us: float | None       # worst release -> end of its work; None: unbounded
    paced_by: str | None            # the writer whose data paces it


@dataclass(frozen=True)
class ExpectedInput:
    """Per reader cycle: the share that finds new data, the share that finds none, and the
    writer's sequences skipped (dropped) per cycle, as the analysis counts them; None: it
    depends on a rate the host's events decide. The prediction makes them (host/theory/predict.py)."""

    reader: str
    buffer: str
    writer: str
    new: float | None
    stale: float | None
    dropped: float | None
    transport_us: float = 0.0       # the mean delay its link's emulated latency and jitter add
    lost_pct: float = 0.0           # the share of the writer's buffers its link's emulation loses


@dataclass(frozen=True)
class ExpectedChain:
    name: str
    processes: tuple[str, ...]
    best_us: float | None
    worst_us: float | None          # None: a step falls ever further behind
    network_us: float = 0.0         # of its latency, the mean its links' emulated delays add


@dataclass(frozen=True)
class Expected:
    """What the analysis reads of a prediction (host/theory/predict.py's Prediction, whose JSON
    form, figures rounded as report.json writes them, from_json reads): per DPU its % compute,
    per process its worst response, per input its shares, per chain its latency."""

    dpus: tuple[ExpectedDpu, ...]
    processes: tuple[ExpectedProcess, ...]
    inputs: tuple[ExpectedInput, ...]
    chains: tuple[ExpectedChain, ...]

    @classmethod
    def from_json(cls, doc: dict[str, Any]) -> Expected:
        return cls(
            dpus=tuple(ExpectedDpu(d["id"], d["compute_pct"], d.get("communicate_pct")) for d in doc["dpus"]),
            processes=tuple(ExpectedProcess(p["name"], p["response_us"], p["paced_by"])
                            for p in doc["processes"]),
            inputs=tuple(ExpectedInput(i["reader"], i["buffer"], i["writer"], i["new"], i["stale"],
                                       i["dropped"], i.get("transport_us", 0.0), i.get("lost_pct", 0.0))
                         for i in doc["inputs"]),
            chains=tuple(ExpectedChain(c["name"], tuple(c["processes"]), c["best_us"], c["worst_us"],
                                       c.get("network_us", 0.0))
                         for c in doc["chains"]))

def charges(links: Sequence[Link], dpus: Sequence[Dpu], buffers: Sequence[Buffer],
            processes: Sequence[Process]) -> tuple[Process, ...]:
    """The processes, each with the CPU its DPU charges it per cycle for its links' costs, as
    dpu/plan.c works them out (keep the two alike). The writer pays, in comm_out, per buffer it
    publishes: per_message_us + per_byte_ns x bytes, and push_byte_ns x bytes for each other DPU
    that reads it. A reader pays, in comm_in: remote_read_us per input written on another DPU,
    every cycle; and its DPU, which receives each message once, pays per_message_us +
    per_byte_ns x bytes per message received, charged to the process that reads the buffer
    there most often (the shortest period, then the first in the DPU's order): a period of its
    per period of the writer on average, the whole ones for the fewest and one more for the most.
    A DPU's speed does not shorten them: they are the bus's and its interfaces', not the code's."""
    link = {k.id: k for k in links}
    if not any(k.costs for k in links):
        return tuple(processes)
    by_id = {p.id: p for p in processes}
    readers: dict[int, list[Process]] = {}
    for p in processes:
        for b in p.inputs:
            readers.setdefault(b, []).append(p)
    out: list[Process] = []
    for p in processes:
        c = {"in_us": 0.0, "in_worst_us": 0.0, "in_best_us": 0.0, "out_us": 0.0}
        for b in (x for x in buffers if x.id in p.outputs):
            k = link[b.link]
            others = len({r.dpu for r in readers.get(b.id, [])} - {p.dpu})
            c["out_us"] += k.per_message_us + (k.per_byte_ns + k.push_byte_ns * others) * b.bytes / 1000
        for b in (x for x in buffers if x.id in p.inputs):
            k, writer = link[b.link], by_id.get(b.writer)
            if writer is None:  # a config without its writer (the rules refuse one): charged nothing
                continue
            remote = k.remote_read_us if writer.dpu != p.dpu else 0.0
            payer = min((r for r in readers[b.id] if r.dpu == p.dpu),
                        key=lambda r: (r.period_us, r.order, r.id))
            message = k.per_message_us + k.per_byte_ns * b.bytes / 1000 if payer.id == p.id else 0.0
            per_cycle = p.period_us / writer.period_us
            c["in_us"] += remote + message * per_cycle
            c["in_worst_us"] += remote + message * math.ceil(per_cycle - 1e-9)
            c["in_best_us"] += remote + message * math.floor(per_cycle + 1e-9)
        out.append(dataclasses.replace(p, charge=Charge(**c)) if any(c.values()) else p)
    return tuple(out)


# --- the model on the wire: config_t's enums, and a System read back from a config_t -------------
COMPUTE = {"sleep": skelmsg.dpu_t.COMPUTE_SLEEP, "wall": skelmsg.dpu_t.COMPUTE_WALL,
           "cpu": skelmsg.dpu_t.COMPUTE_CPU, "work": skelmsg.dpu_t.COMPUTE_WORK}
NETWORK = {"emulated": skelmsg.config_t.NETWORK_EMULATED, "kernel": skelmsg.config_t.NETWORK_KERNEL}
EXECUTIVE = {"cyclic": skelmsg.dpu_t.EXECUTIVE_CYCLIC, "threads": skelmsg.dpu_t.EXECUTIVE_THREADS}
SYNC = {"periodic": skelmsg.process_t.SYNC_PERIODIC, "data": skelmsg.process_t.SYNC_DATA,
        "event": skelmsg.process_t.SYNC_EVENT}
EVENT_KIND = {"host": skelmsg.event_source_t.KIND_HOST, "periodic": skelmsg.event_source_t.KIND_PERIODIC,
              "poisson": skelmsg.event_source_t.KIND_POISSON, "bursts": skelmsg.event_source_t.KIND_BURSTS}
FROM_CONFIG = "table"   # a varying compute read back from a config: its quantile table, not its kind


def _named(names: dict[str, int], value: int) -> str:
    """The name of a wire enum's value; ValueError for a value the contract does not name (a
    damaged message: LCM checks a message's type, not its values)."""
    for name, v in names.items():
        if v == value:
            return name
    raise ValueError(f"{value} is none of {', '.join(f'{v} ({name})' for name, v in names.items())}")


def _link(link: skelmsg.link_t) -> Link:
    burst = LossBurst(link.burst_enter_pct, link.burst_leave_pct, link.burst_loss_pct)
    return Link(link.id, link.name, link.url or "local", link.bandwidth_mbps or None,
                latency_us=link.latency_us, jitter_us=link.jitter_us,
                jitter="normal" if link.jitter == skelmsg.link_t.JITTER_NORMAL else "uniform",
                loss_pct=link.loss_pct, burst=burst if link.burst_enter_pct > 0 else None,
                per_message_us=link.per_message_us, per_byte_ns=link.per_byte_ns,
                push_byte_ns=link.push_byte_ns, remote_read_us=link.remote_read_us, queue_us=link.queue_us)


def from_config(msg: skelmsg.config_t) -> System:
    """The System a config_t describes (host/live/wire.py writes one from a System): what a run's
    DPUs were sent, as the analysis reads it from the log. What the config does not carry keeps
    its default: the run's length and stop_on, a varying compute's kind (its
    quantile table is carried), the reference, the overrides; the path is the run's system.yaml."""
    links = tuple(_link(k) for k in msg.links)
    buffers = tuple(Buffer(b.id, b.name, b.bytes, b.link, b.writer) for b in msg.buffers)
    processes = tuple(
        Process(id=p.id, name=p.name, dpu=p.dpu, order=p.order, period_us=p.period_us,
                compute_us=p.compute_us, sync=_named(SYNC, p.sync), inputs=tuple(p.inputs),
                required=tuple(b for b, wait in zip(p.inputs, p.required, strict=True) if wait),
                outputs=tuple(p.outputs),
                varying=Varying(FROM_CONFIG, tuple(p.quantiles_us), given={}) if p.quantiles_us else None,
                priority=p.priority, event=p.event, queue=p.queue, emits=tuple(p.emits),
                code=Code(p.library, p.function) if p.library else None)
        for p in msg.processes)
    dpus = tuple(Dpu(d.id, d.host, None if d.cpu < 0 else d.cpu, _named(COMPUTE, d.compute),
                     _named(EXECUTIVE, d.executive), d.speed, d.minor_cycle_us, tuple(d.links))
                 for d in msg.dpus)
    return System(
        name=msg.system, path=Path("system.yaml"), source_text=msg.source,
        links=links,
        dpus=dpus,
        buffers=buffers,
        processes=charges(links, dpus, buffers, processes),
        run=RunRules(cycles=None, duration_s=None, warmup_cycles=msg.warmup_cycles,
                     lockout_cycles=msg.lockout_cycles, stop_on=(), late_pct=msg.late_pct,
                     too_late_pct=msg.too_late_pct, seed=msg.seed,
                     network=_named(NETWORK, msg.network)),
        chains=tuple(Chain(c.name, tuple(c.processes)) for c in msg.chains),
        reference=None,
        events=tuple(Event(e.name, _named(EVENT_KIND, e.kind), e.dpu, e.period_us, e.jitter_us, e.rate_hz,
                           e.count, e.spacing_us) for e in msg.events),
        writer_ports={(b.link, b.writer): urlsplit(b.url).port or 0 for b in msg.buffers if b.url},
        buffer_urls={b.id: b.url for b in msg.buffers})
