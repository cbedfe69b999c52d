"""The system file's schema: what each section may say (the pydantic models, the only
place the file's schema lives); rules.resolve() turns it into host/model.py's records.

Per-field checks (types, ranges, names, URLs) are here; checks across sections
(references, writers, reachability, minor cycles) are rules.py's.
"""

from __future__ import annotations

import ipaddress
import math
import re
import urllib.parse
from dataclasses import dataclass
from typing import Annotated, Any, Literal

from pydantic import (
    AfterValidator,
    BaseModel,
    ConfigDict,
    Discriminator,
    PlainValidator,
    Tag,
    ValidationInfo,
    field_validator,
    model_validator,
)

from skelmsg import contract

from .yamlfile import show

DEFAULT_LINK = "bus"
MAX_ID = 32767                      # ids travel as int16
MAX_INT32 = 2**31 - 1               # periods, compute times and run counts travel as int32
ABSURD_COMPUTE_PERIODS = 100        # compute_us beyond this many periods is a units mistake
DEFAULT_RUN_CYCLES = 2000               # when the file gives neither cycles nor duration_s


# --- field types ---------------------------------------------------------------------------

def _id(v: int) -> int:
    """from 1 to 32767 (ids travel as int16)"""
    if not 1 <= v <= MAX_ID:
        raise ValueError(f"must be an id from 1 to {MAX_ID}, got {v}")
    return v


def _micros(v: int) -> int:
    """positive, at most 2^31 - 1 us"""
    if v <= 0:
        raise ValueError(f"must be a positive number of microseconds, got {v}")
    if v > MAX_INT32:
        raise ValueError(f"must be at most {MAX_INT32} microseconds, got {v}")
    return v


def _compute_us(v: int) -> int:
    """0 (a relay) or positive, at most 2^31 - 1 us"""
    # 0 models a process that only communicates (a relay), and measures the executive's own cost.
    if v < 0:
        raise ValueError(f"must be 0 or more microseconds, got {v}")
    return 0 if v == 0 else _micros(v)


def _period(v: int) -> int:
    """positive, at most the contract's MAX_PERIOD_US"""
    # The DPU refuses a longer period (config.c): said here, before anything runs.
    v = _micros(v)
    if v > contract.MAX_PERIOD_US:
        limit = contract.MAX_PERIOD_US
        raise ValueError(f"must be at most {limit} microseconds ({limit // 10**6} s), got {v}")
    return v


def _bytes(v: int) -> int:
    """positive, at most the contract's MAX_BUFFER_BYTES (4 MiB)"""
    if v <= 0:
        raise ValueError(f"must be a positive number of bytes, got {v}")
    if v > contract.MAX_BUFFER_BYTES:  # beyond this a "buffer" is a file transfer
        raise ValueError(f"{v} bytes is absurd for one buffer "
                         f"(limit {contract.MAX_BUFFER_BYTES >> 20} MiB = {contract.MAX_BUFFER_BYTES})")
    return v


# Names become LCM channels (SKEL_BUF_<name>, SKEL_EVENT_<name>) and -s targets (dots, '=').
NAME = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def name_problem(v: str) -> str:
    """What is wrong with `v` as a name ('' when nothing): the system file's and `skel event`'s."""
    if not NAME.fullmatch(v):
        return f"must be a name of letters, digits and _ not starting with a digit, got {show(v)}"
    if len(v) > contract.MAX_NAME:  # the DPUs refuse longer: SKEL_EVENT_<name> would outgrow LCM's channels
        return (f"must be at most {contract.MAX_NAME} characters (it names an LCM channel), "
                f"got {len(v)}: {show(v)}")
    return ""


def _name(v: str) -> str:
    """letters, digits and _, not starting with a digit; at most the contract's MAX_NAME characters"""
    problem = name_problem(v)
    if problem:
        raise ValueError(problem)
    return v


def _ref(v: Any) -> int | str:
    """a buffer id or name"""
    if isinstance(v, bool) or not isinstance(v, int | str):
        raise ValueError(f"must be a buffer id or name, got {show(v)}")
    return v


def _between(low: int, high: int, unit: str = "") -> Any:
    """An int in [low, high]; `high` is the wire field's limit, so encoding never overflows."""
    def check(v: int) -> int:
        if v < low:
            raise ValueError(f"must be at least {low}{unit}, got {v}")
        if v > high:
            raise ValueError(f"must be at most {high}{unit}, got {v}")
        return v
    check.__doc__ = f"from {low} to {high}{unit}"
    return AfterValidator(check)


def _at_least_items(n: int) -> Any:
    def check(v: list[Any]) -> list[Any]:
        if len(v) < n:
            raise ValueError(f"needs at least {n} item(s)")
        return v
    check.__doc__ = f"at least {n} item(s)"
    return AfterValidator(check)


def _at_most_items(n: int) -> Any:
    def check(v: list[Any]) -> list[Any]:
        if len(v) > n:
            raise ValueError(f"takes at most {n} item(s), got {len(v)}")
        return v
    check.__doc__ = f"at most {n} item(s)"
    return AfterValidator(check)


def _nonempty(v: str) -> str:
    """not empty"""
    if not v.strip():
        raise ValueError("must not be empty")
    return v


def _positive(v: float) -> float:
    """a positive finite number"""
    if not (math.isfinite(v) and v > 0):
        raise ValueError(f"must be a positive number, got {show(v)}")
    return v


def _within(low: float, high: float) -> Any:
    """A number in [low, high]: the wire contract's limits, which the DPUs check too."""
    def check(v: float) -> float:
        if not low <= v <= high:
            raise ValueError(f"must be from {low:g} to {high:g}, got {show(v)}")
        return v
    check.__doc__ = f"from {low:g} to {high:g}"
    return AfterValidator(check)


Id = Annotated[int, AfterValidator(_id)]
Name = Annotated[str, AfterValidator(_name)]
Micros = Annotated[int, AfterValidator(_micros)]
Period = Annotated[int, AfterValidator(_period)]
Bytes = Annotated[int, AfterValidator(_bytes)]
Ref = Annotated[int | str, PlainValidator(_ref)]
Positive = Annotated[float, AfterValidator(_positive)]
NonEmpty = Annotated[str, AfterValidator(_nonempty)]


class _Spec(BaseModel):
    # strict: a quoted "5000" or a `yes` is a mistake to report, not to coerce.
    # use_attribute_docstrings: the string under a field is its description, which the
    # documentation's system-file reference prints (docs/hooks.py).
    model_config = ConfigDict(extra="forbid", strict=True, frozen=True, use_attribute_docstrings=True)


# --- the schema ----------------------------------------------------------------------------

Percent = Annotated[float, _within(0, 100)]
Latency = Annotated[int, _between(0, contract.MAX_PERIOD_US, " us")]
Bandwidth = Annotated[float, _within(contract.MIN_BANDWIDTH_MBPS, contract.MAX_BANDWIDTH_MBPS)]


class LossBurstSpec(_Spec):
    """Gilbert-Elliott: the link is good or bad; before each version it may change state, then
    the version is lost with its state's loss (the good state's is the link's `loss_pct`)."""

    enter_pct: Percent
    """Per version, the chance that a good link turns bad."""
    leave_pct: Annotated[float, _within(0, 100), AfterValidator(_positive)]
    """Per version, the chance that a bad link turns good again: a burst lasts 100 / leave_pct
    versions on average."""
    loss_pct: Percent = 100.0
    """The loss in the bad state."""
def _cost(v: float) -> float:
    """from 0 to the contract's MAX_LINK_COST"""
    # The DPUs refuse a larger one (config.c): beyond it a cost is a units mistake.
    if not (math.isfinite(v) and 0 <= v <= contract.MAX_LINK_COST):
        raise ValueError(f"must be a cost from 0 to {contract.MAX_LINK_COST:g}, got {show(v)}")
    return v


NotNegative = Annotated[float, AfterValidator(_cost)]
COSTS = ("per_message_us", "per_byte_ns", "push_byte_ns", "remote_read_us")   # a link's CPU costs
QUEUE_US = 100_000   # a bandwidth-limited link's transmit queue when the file gives none: 100 ms


@dataclass(frozen=True)
class Preset:
    source: str                     # where its figures come from
    values: dict[str, float]        # LinkSpec fields: the costs and bandwidth_mbps


# Built-in links: only figures of fields the DPUs and `skel check` act on, each with its source.
PRESETS = {
    "vme": Preset("the paper's VME/VSB bus with common memory: the `push` model fitted to Table 1 "
                  "(host/theory/busfit.py; explanation/paper.md shows the fit)",
                  {"push_byte_ns": 1352, "remote_read_us": 58.8}),
    "can-1m": Preset("high-speed CAN at its highest bit rate, 1 Mbit/s (ISO 11898-2); its CPU costs "
                     "are the controller's and driver's: give them measured",
                     {"bandwidth_mbps": 1}),
    "ethernet-100m": Preset("Fast Ethernet, 100 Mbit/s (IEEE 802.3u, 100BASE-TX); its CPU costs are "
                            "the network stack's, which a run on a real network measures itself",
                            {"bandwidth_mbps": 100}),
}


def _preset(v: str) -> str:
    if v not in PRESETS:
        raise ValueError(f"no preset {show(v)}; presets: {', '.join(PRESETS)}")
    return v


_preset.__doc__ = "one of: " + "; ".join(
    f"`{name}` ({', '.join(f'{k} {v:g}' for k, v in p.values.items())}: {p.source})"
    for name, p in PRESETS.items())


class LinkSpec(_Spec):
    name: Name
    """The link's name, which buffers and DPUs refer to."""
    url: str
    """`local` (in-process memory: writer and readers on one DPU) or an `udpm://` URL. The first link's URL
    is the control URL; each process writing to the link gets the next multicast group and port after
    it. `ttl=0` never leaves the machine, `ttl=1` for a lab."""
    bandwidth_mbps: Bandwidth | None = None
    """What the link carries, in Mbit/s. Each reading DPU emulates one transmitter for the link: every
    message on it takes its bytes on the wire (payload and headers) at this rate, one after another in
    the order sent, before the latency below. `skel check` warns when its buffers need more, and the
    report says the link saturated when its writers offered more."""
    queue_us: Latency | None = None
    """With `bandwidth_mbps`: the longest a message waits for the transmitter. One that would wait
    longer is dropped, as a full transmit queue drops it, and counted as lost. Default 100000 (100 ms):
    set your controller's or network stack's."""
    # The link's transport, emulated by the reading DPUs (dpu/buffers.c): one block, kept last.
    latency_us: Latency = 0
    """The link's one-way latency: a reader sees a buffer no earlier than its send time plus this (plus
    a jitter draw), in the order it was sent. Emulated by the reading DPU, on any link, local too."""
    jitter_us: Latency = 0
    """The spread of each buffer's latency: see `jitter`. A delay is never below 0."""
    jitter: Literal["uniform", "normal"] = "uniform"
    """`uniform` (latency_us ± jitter_us) or `normal` (jitter_us the standard deviation, cut at 3).
    The draws come from run.seed: a simulation repeats."""
    loss_pct: Percent = 0.0
    """The chance that a buffer is lost, drawn independently by each reading DPU (from run.seed). A
    lost buffer is never seen by that DPU's readers; the report counts it as lost."""
    loss_burst: LossBurstSpec | None = None
    """Losses that come in bursts (Gilbert-Elliott): `enter_pct`, `leave_pct`, and `loss_pct` in
    the bad state (default 100); `loss_pct` above is then the good state's."""
    preset: Annotated[str, AfterValidator(_preset)] | None = None
    """A built-in link whose figures this link takes (`bandwidth_mbps` and the costs below); a field
    given beside it overrides the preset's."""
    per_message_us: NotNegative | None = None
    """CPU cost, in us: the writer's per message it publishes (comm_out), and each reading DPU's per
    message it receives (comm_in of its fastest process reading the buffer). Default 0."""
    per_byte_ns: NotNegative | None = None
    """CPU cost per byte of those messages, in ns, charged as `per_message_us` is. Default 0."""
    push_byte_ns: NotNegative | None = None
    """CPU cost, in ns, of the writer per byte it publishes for each other DPU that reads the buffer
    (it copies the buffer into that DPU's memory), in comm_out. Default 0."""
    remote_read_us: NotNegative | None = None
    """CPU cost, in us, of a process every cycle it runs, per input written on another DPU (the
    handshake over the bus), in comm_in, new data or not. Default 0."""

    @model_validator(mode="after")
    def _queue(self) -> LinkSpec:
        if self.queue_us is not None and self.figure("bandwidth_mbps") is None:
            raise ValueError("queue_us is the transmit queue of a bandwidth-limited link: "
                             "give bandwidth_mbps too")
        if self.queue_us == 0:
            raise ValueError("queue_us must be at least 1 us: a queue of 0 would drop every message")
        return self

    @model_validator(mode="after")
    def _costs(self) -> LinkSpec:
        # A local link is memory inside one DPU: there is no bus whose cost it could charge.
        if self.url == "local" and (self.preset or any(getattr(self, f) for f in COSTS)):
            raise ValueError("a `local` link is memory inside one DPU and charges no cost: "
                             "give the cost to an udpm:// link")
        if self.url == "local" and self.bandwidth_mbps is not None:
            raise ValueError("a `local` link is memory inside one DPU: it has no bandwidth to share; "
                             "give bandwidth_mbps to an udpm:// link")
        return self

    def figure(self, name: str) -> float | None:
        """A cost or the bandwidth as this link has it: given, else its preset's (None: neither)."""
        given = getattr(self, name)
        return given if given is not None else PRESETS.get(self.preset or "", Preset("", {})).values.get(name)

    @field_validator("url")
    @classmethod
    def _url(cls, v: str) -> str:
        if v == "local":
            return v
        if not re.fullmatch(r"udpm://\S*", v):
            raise ValueError(f"must be `local` or an udpm:// URL, got {show(v)}")
        try:  # LCM would only fail later, on every DPU at once
            where = urllib.parse.urlsplit(v)
            port, group = where.port, where.hostname
            if group and not ipaddress.ip_address(group).is_multicast:
                raise ValueError(f"{group} is not a multicast group (224.0.0.0 to 239.255.255.255)")
        except ValueError as e:
            raise ValueError(f"{v}: {e}") from None
        if port == 0:
            raise ValueError(f"{v}: port 0 cannot be joined")
        return v


class DpuSpec(_Spec):
    id: Id
    """The DPU's id, unique in the system."""
    host: NonEmpty = "localhost"
    """The machine it runs on: `skel-dpu --id auto` on a host picks the DPU with its host name; `skel up`
    and `--spawn` start the DPUs whose host is `localhost` or this machine's name."""
    cpu: Annotated[int, _between(0, MAX_ID)] | None = None
    """Pin the executive thread to this CPU (a DPU refuses one its host lacks; `skel run` on that host
    keeps its own work off it)."""
    compute: Literal["sleep", "wall", "cpu", "work"] = "sleep"
    """How a computation is emulated: `sleep` (the DPU sleeps for it; a processor of its own), `wall`
    (spins on the wall clock), `cpu` (spins on the thread's CPU clock), `work` (a calibrated number of
    iterations)."""
    executive: Literal["cyclic", "threads"] = "cyclic"
    """`cyclic` (the paper's procedural model: processes in order in each minor cycle) or `threads` (the
    tasking executive: fixed-priority preemptive)."""
    speed: Annotated[Positive, _within(contract.MIN_SPEED, contract.MAX_SPEED)] = 1.0
    """Speed factor: every compute time on this DPU is divided by it."""
    minor_cycle_us: Micros | None = None
    """The DPU's minor cycle; default: the gcd of its processes' periods. At least 100 us."""
    links: list[Name] | None = None
    """The links this DPU can reach; default: every link."""


class BufferSpec(_Spec):
    id: Id
    """The buffer's id, unique in the system."""
    name: Name
    """The buffer's name (it names an LCM channel)."""
    bytes: Bytes
    """The dummy buffer's size."""
    link: Name | None = None
    """The link it travels on; default: the first udpm link."""


def _not_negative(v: float) -> float:
    """0 or more us"""
    if not (math.isfinite(v) and v >= 0):
        raise ValueError(f"must be a number of microseconds, at least 0, got {show(v)}")
    return v


class ComputeSpec(_Spec):
    """A compute time that varies, in us: a distribution within [min, max], or measured samples."""
    dist: Literal["uniform", "normal", "lognormal", "exponential"] | None = None
    """The distribution the compute time is drawn from (give `dist` or `samples`)."""
    samples: NonEmpty | None = None
    """A CSV of compute times measured on real code, in us, one per line (a header line is allowed), beside
    the system file."""
    mean: Positive | None = None
    """The mean of the time itself (normal, lognormal, exponential)."""
    sd: Positive | None = None
    """The standard deviation of the time itself (normal, lognormal)."""
    min: Annotated[float, AfterValidator(_not_negative)] | None = None
    """The smallest time drawn (default 0)."""
    max: Positive | None = None
    """The largest time drawn: the worst case, which the prediction uses."""

    @model_validator(mode="after")
    def _parameters(self) -> ComputeSpec:
        if (self.dist is None) == (self.samples is None):
            raise ValueError("give `dist` (uniform, normal, lognormal, exponential) or `samples: FILE`")
        given = {k for k in ("mean", "sd", "min", "max") if getattr(self, k) is not None}
        kind = self.dist or "samples"
        needs, allowed = {
            "uniform": ({"min", "max"}, {"min", "max"}),
            "normal": ({"mean", "sd", "max"}, {"mean", "sd", "min", "max"}),
            "lognormal": ({"mean", "sd", "max"}, {"mean", "sd", "min", "max"}),
            "exponential": ({"mean", "max"}, {"mean", "min", "max"}),
            "samples": (set(), set()),
        }[kind]
        if needs - given:
            missing = ", ".join(sorted(needs - given))
            raise ValueError(f"{kind} needs {missing} (max bounds the worst case)")
        if given - allowed:
            extra = ", ".join(sorted(given - allowed))
            raise ValueError(f"{kind} takes no {extra}" + ("; the samples are used as measured"
                                                           if kind == "samples" else ""))
        low = self.min or 0.0
        if self.max is not None and low > self.max:
            raise ValueError(f"the bounds are empty: min {low:g} us > max {self.max:g} us")
        return self


def _compute_kind(v: Any) -> str:
    return "<distribution>" if isinstance(v, dict) else "<number>"


# compute_us: a number, or a mapping describing how it varies. The tags route a value to
# one branch, so an error names that branch's problem only (yamlfile.field_path skips them).
Compute = Annotated[
    Annotated[int, AfterValidator(_compute_us), Tag("<number>")]
    | Annotated[ComputeSpec, Tag("<distribution>")],
    Discriminator(_compute_kind),
]


def _library(v: str) -> str:
    """a library's name NAME (libNAME.so in a DPU's --lib-dir), never a path"""
    if "/" in v or v.startswith(".") or v.endswith(".so"):
        raise ValueError(f"must name a library (NAME for libNAME.so in the DPU's --lib-dir), not a path: "
                         f"got {show(v)}")
    return _name(v)


class CodeSpec(_Spec):
    """Real code in place of the emulated computation: a step function in a shared library built against
    include/skel_step.h, which each DPU loads only from its own `--lib-dir`."""
    library: Annotated[str, AfterValidator(_library)]
    """The library's name: `sum` loads `libsum.so` from the DPU's `--lib-dir`, never a path."""
    function: Name
    """The step function, called once per cycle (its optional `FUNCTION_init` and `FUNCTION_fini` around
    each run)."""


class ProcessSpec(_Spec):
    id: Id
    """The process's id, unique in the system."""
    name: Name
    """The process's name."""
    dpu: Id
    """The DPU it runs on."""
    period_us: Period
    """Its period, a multiple of its DPU's minor cycle (`sync: event`: the least time between two of its
    cycles)."""
    compute_us: Compute
    """The emulated computation per cycle, in us (0: a relay that only communicates), or how it varies: a
    distribution or measured samples."""
    compute: CodeSpec | None = None
    """Real code that runs in place of the emulated computation (`{library: NAME, function: SYMBOL}`), on
    the cyclic executive; `compute_us` stays the prediction's assumption."""
    sync: Literal["periodic", "data", "event"] = "periodic"
    """What starts a cycle: `periodic` (every period), `data` (released every period, then waits for new
    data on its `required` inputs), `event` (one cycle per event it awaits)."""
    inputs: list[Ref] = []
    """The buffers it reads, by name or id."""
    required: list[Ref] | None = None
    """`sync: data` only: the inputs it waits for; default: all inputs."""
    outputs: list[Ref] = []
    """The buffers it writes; each buffer has exactly one writer."""
    order: Annotated[int, _between(1, MAX_ID)] | None = None
    """Its position in its DPU's minor cycle; default: file order."""
    priority: Annotated[int, _between(1, contract.MAX_PRIORITY)] | None = None
    """`executive: threads` only: 1..99, higher first; default rate-monotonic. Either every process of a
    tasking DPU gives one or none does."""
    event: Name | None = None
    """`sync: event` only: the event it awaits."""
    queue: Annotated[int, _between(1, contract.MAX_QUEUE)] | None = None
    """`sync: event` only: how many waiting events it keeps (1: only the newest; N: up to N, oldest first);
    default 1."""
    emits: Annotated[list[Name], _at_most_items(contract.MAX_EMITS)] = []
    """Events it fires at the end of each of its cycles, after its outputs."""


class EventSpec(_Spec):
    """A named event's source: the host (`skel event NAME`) or a generator a DPU runs."""
    name: Name
    """The event's name (it names an LCM channel)."""
    kind: Literal["host", "periodic", "poisson", "bursts"]
    """Its source: `host` (sent by `skel event NAME`) or a generator the DPU `dpu` runs: `periodic`,
    `poisson` or `bursts`."""
    dpu: Id | None = None
    """The DPU that generates it (every kind but `host`)."""
    period_us: Micros | None = None
    """`periodic`: between events; `bursts`: between burst starts."""
    jitter_us: Annotated[int, _between(0, MAX_INT32, " us")] | None = None
    """`periodic`: each event moved by a uniform draw in +-jitter_us (below half the period)."""
    rate_hz: Annotated[Positive, _within(contract.MIN_RATE_HZ, contract.MAX_RATE_HZ)] | None = None
    """`poisson`: the mean rate (exponential gaps)."""
    count: Annotated[int, _between(1, MAX_INT32)] | None = None
    """`bursts`: events in a burst."""
    spacing_us: Micros | None = None
    """`bursts`: between the events of a burst."""

    @model_validator(mode="after")
    def _parameters(self) -> EventSpec:
        needs, allowed = {
            "host": (set(), set()),
            "periodic": ({"dpu", "period_us"}, {"dpu", "period_us", "jitter_us"}),
            "poisson": ({"dpu", "rate_hz"}, {"dpu", "rate_hz"}),
            "bursts": ({"dpu", "period_us", "count", "spacing_us"},) * 2,
        }[self.kind]
        given = {k for k in ("dpu", "period_us", "jitter_us", "rate_hz", "count", "spacing_us")
                 if getattr(self, k) is not None}
        if needs - given:
            raise ValueError(f"{self.kind} needs {', '.join(sorted(needs - given))}")
        if given - allowed:
            raise ValueError(f"{self.kind} takes no {', '.join(sorted(given - allowed))}"
                             + ("; the host sends it with `skel event`" if self.kind == "host" else ""))
        if self.jitter_us is not None and self.period_us is not None and 2 * self.jitter_us >= self.period_us:
            raise ValueError(f"jitter_us {self.jitter_us} must be below half the period "
                             f"({self.period_us} us): events would change order")
        if self.count is not None and self.spacing_us is not None and self.period_us is not None \
                and (self.count - 1) * self.spacing_us >= self.period_us:
            raise ValueError(f"a burst of {self.count} events {self.spacing_us} us apart does not "
                             f"fit in its period of {self.period_us} us")
        return self


class Run(_Spec):
    """The run: its length, warm-up, lockout rule and when to stop early."""
    cycles: Annotated[int, _between(1, MAX_INT32, " cycle")] | None = None
    """Run length, in cycles of the shortest period (or give `duration_s`; neither: 2000 cycles)."""
    duration_s: Positive | None = None
    """Run length in seconds (or give `cycles`)."""
    warmup_cycles: Annotated[int, _between(0, MAX_INT32)] = 50
    """Cycles of each DPU's slowest process excluded from every measure."""
    lockout_cycles: Annotated[int, _between(1, MAX_INT32, " cycle")] = 10
    """A cycle not completed this many periods after its release is a lockout."""
    stop_on: list[Literal["lockout", "jam", "behind", "stall", "dpu_lost"]] = ["lockout"]
    """Faults that end the run early, one lockout window (lockout_cycles x the longest period, at most 1 s)
    after the first."""
    late_pct: Annotated[int, _between(1, MAX_INT32, " %")] = 20
    """Lateness (start - the schedule's start) above this % of the period is late."""
    too_late_pct: Annotated[int, _between(1, MAX_INT32, " %")] = 100
    """... and above this % is too late (at least `late_pct`)."""
    seed: Annotated[int, _between(0, 2**63 - 1)] = 1
    """Every random draw of a run (varying compute, generated events): same seed, same draws."""
    network: Literal["kernel", "emulated"] = "kernel"
    """How the reading DPUs give links their latency, jitter, loss and bandwidth. `kernel`: with `tc` (an
    ifb device, netem, tbf) and nftables on the reading host where it can (root, and a link whose writers
    are all on other hosts), emulated by the DPU where it cannot; `emulated`: always by the DPU. Each
    property's path is in the run's output and `skel status`."""

    @model_validator(mode="after")
    def _consistent(self) -> Run:
        if self.cycles is not None and self.duration_s is not None:
            raise ValueError("give cycles or duration_s, not both")
        if self.too_late_pct < self.late_pct:
            raise ValueError(f"too_late_pct ({self.too_late_pct}) must be at least "
                             f"late_pct ({self.late_pct})")
        return self


class ChainSpec(_Spec):
    name: NonEmpty | None = None
    """The chain's name; default: its processes joined."""
    processes: list[Name]
    """The end-to-end path, head first: each step reads a buffer the step before writes. A plain list is
    accepted."""

    @model_validator(mode="before")
    @classmethod
    def _plain_list(cls, data: Any) -> Any:
        return {"processes": data} if isinstance(data, list) else data


class ReferenceDpu(_Spec):
    """One DPU's row of a published measurement (e.g. the paper's Table 1)."""
    compute_pct: float
    """Published % compute."""
    communicate_pct: float
    """Published % communicate."""
    wait_pct: float
    """Published % wait."""
    cycle_ms: float | None = None
    """Published measured cycle."""
    modeled_cycle_ms: float | None = None
    """Published modelled cycle."""


class Reference(_Spec):
    """Published results to compare a run with (`skel run --compare-paper`); not sent to DPUs."""
    source: str
    """Where the numbers come from (e.g. `Wheatley & Michaloski 1990, Table 1`)."""
    dpus: dict[int, ReferenceDpu] = {}
    """Per DPU id, its published row."""


class SystemSpec(_Spec):
    system: NonEmpty
    """The system's name: it names the run directories."""
    links: list[LinkSpec] | None = None
    """The links; default: one link `bus` on the contract's default URL."""
    dpus: Annotated[list[DpuSpec], _at_least_items(1)]
    """The processing units."""
    buffers: list[BufferSpec] = []
    """The dummy buffers between processes."""
    processes: Annotated[list[ProcessSpec], _at_least_items(1)]
    """The processes (the paper's GCCPs)."""
    run: Run = Run()
    """How a run goes: its length, warm-up, lockout rule and when to stop early."""
    chains: list[ChainSpec] = []
    """End-to-end paths whose latency the report measures."""
    events: list[EventSpec] = []
    """Sources of events besides emitting processes."""
    reference: Reference | None = None
    """Published numbers to print beside ours (`skel run --compare-paper`); not sent to the DPUs."""

    @field_validator("buffers", "chains", "events", "run", mode="before")
    @classmethod
    def _empty_section(cls, v: Any, info: ValidationInfo) -> Any:
        # `run:` with every line commented out is an empty section, not an error.
        if v is None:
            return {} if info.field_name == "run" else []
        return v
