"""Which bus reproduces a published % communicate: a cost model of a few parameters, fitted.

The paper's Table 1 measured SERVO on a 1990 VME/VSB system with common memory; our DPUs
measure what a modern network costs. To reproduce the table, each DPU's communication is
modelled as a handful of traffic counts (traffic(): per second, from the system file and the
prediction's rates), each count with a cost (a Model names which). fit() finds the costs by
least squares over the DPUs of the file's `reference:`, none negative, and gives each DPU's
% compute, % communicate and % wait beside the reference's: the columns a run would measure
if the DPUs charged those costs, before the platform's own.
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass, fields

import numpy as np

from ..model import ReferenceDpu, System
from .predict import Prediction, predict


@dataclass(frozen=True)
class Traffic:
    """One DPU's communication each second, counted the ways a bus may charge it."""

    published: float        # messages its processes publish
    published_bytes: float
    received: float         # messages of the buffers its processes read, once per DPU (its own too)
    received_bytes: float
    pushed_bytes: float     # bytes it publishes times the other DPUs that read them
    accesses: float         # every input read and output written, each cycle of each process
    access_bytes: float
    remote_reads: float     # each process's inputs written on another DPU, every cycle it runs


def traffic(system: System, prediction: Prediction) -> dict[int, Traffic]:
    """Per DPU id, its traffic at the prediction's rates (a process of unknown rate counts none)."""
    rate = {p.name: p.rate_hz or 0.0 for p in prediction.processes}
    counts = {d.id: dict.fromkeys((f.name for f in fields(Traffic)), 0.0) for d in system.dpus}
    for p in system.processes:
        mine, hz = counts[p.dpu], rate[p.name]
        for b in map(system.buffer, p.outputs):
            reading = {r.dpu for r in system.readers(b.id)}
            mine["published"] += hz
            mine["published_bytes"] += hz * b.bytes
            mine["pushed_bytes"] += hz * b.bytes * len(reading - {p.dpu})
            for d in reading:
                counts[d]["received"] += hz
                counts[d]["received_bytes"] += hz * b.bytes
        for b in map(system.buffer, (*p.inputs, *p.outputs)):
            mine["accesses"] += hz
            mine["access_bytes"] += hz * b.bytes
        mine["remote_reads"] += hz * sum(system.process(b.writer).dpu != p.dpu
                                         for b in map(system.buffer, p.inputs))
    return {d: Traffic(**c) for d, c in counts.items()}


@dataclass(frozen=True)
class Cost:
    name: str               # as a link field would name it
    unit: str               # us | ns
    counts: tuple[str, ...]  # the Traffic fields it is charged on, summed
    meaning: str


@dataclass(frozen=True)
class Model:
    name: str
    meaning: str
    costs: tuple[Cost, ...]


PER_MESSAGE = Cost("per_message_us", "us", ("published", "received"),
                   "the writer per message it publishes, each reading DPU per message it receives")
PER_BYTE = Cost("per_byte_ns", "ns", ("published_bytes", "received_bytes"),
                "the same, per byte")
PUSH_BYTE = Cost("push_byte_ns", "ns", ("pushed_bytes",),
                 "the writer, per byte, for each other DPU that reads it: it copies the buffer "
                 "over the bus into that DPU's memory")
REMOTE_READ = Cost("remote_read_us", "us", ("remote_reads",),
                   "a process, every cycle, for each input written on another DPU: the handshake "
                   "(lock, new-data flag) over the bus")
MODELS = (
    Model("agreement", "the link model's two costs as agreed (sender and each reader)",
          (PER_MESSAGE, PER_BYTE)),
    Model("common-memory", "every process reads each input and writes each output in a common "
          "memory every cycle", (Cost("per_access_us", "us", ("accesses",), "each read or write"),
                                 Cost("per_access_byte_ns", "ns", ("access_bytes",), "per byte of it"))),
    Model("write-read", "writing and reading cost differently: the writer per byte it publishes, "
          "each reading DPU per message and per byte it receives",
          (Cost("write_byte_ns", "ns", ("published_bytes",), "the writer, per byte"),
           Cost("read_message_us", "us", ("received",), "each reading DPU, per message"),
           Cost("read_byte_ns", "ns", ("received_bytes",), "each reading DPU, per byte"))),
    Model("agreement+push", "the agreed per-message cost, and the writer's copy into each reader",
          (PER_MESSAGE, PUSH_BYTE)),
    Model("push", "the writer copies each buffer over the bus into every other DPU that reads it; "
          "a reader's handshake per remote input every cycle", (PUSH_BYTE, REMOTE_READ)),
)
CHOSEN = "push"
SCALE = {"us": 1e-6, "ns": 1e-9}    # a cost's unit in seconds


@dataclass(frozen=True)
class Row:
    """One DPU: the reference's three columns and the model's."""

    dpu: int
    paper: ReferenceDpu
    compute_pct: float
    communicate_pct: float
    wait_pct: float
    demand_pct: float       # compute + communicate asked of the DPU; above 100 it falls behind
    cycle_ms: float         # its modelled cycle, stretched by a demand above 100 %

    @property
    def residuals(self) -> tuple[float, float, float]:
        """Model minus paper: compute, communicate, wait (points)."""
        return (self.compute_pct - self.paper.compute_pct,
                self.communicate_pct - self.paper.communicate_pct, self.wait_pct - self.paper.wait_pct)


@dataclass(frozen=True)
class Fit:
    model: Model
    values: tuple[float, ...]   # per cost of the model, in its unit
    rows: tuple[Row, ...]
    # per row, its % communicate by the model fitted to the other rows alone, minus the
    # reference's: how well the model predicts a DPU it was not fitted to
    left_out: tuple[float, ...]

    @property
    def worst(self) -> float:
        """The largest residual over the twelve cells (points)."""
        return max(abs(r) for row in self.rows for r in row.residuals)

    @property
    def rms_communicate(self) -> float:
        return float(np.sqrt(np.mean([row.residuals[1] ** 2 for row in self.rows])))


def _nonnegative_lstsq(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Least squares with no negative solution: the best over every subset of columns left free
    (the others held at 0); a model has two or three costs, so at most eight subsets."""
    best, best_sse = np.zeros(a.shape[1]), float(b @ b)
    for n in range(1, a.shape[1] + 1):
        for cols in itertools.combinations(range(a.shape[1]), n):
            x, *_ = np.linalg.lstsq(a[:, cols], b, rcond=None)
            if (x < 0).any():
                continue
            full = np.zeros(a.shape[1])
            full[list(cols)] = x
            sse = float(np.sum((a @ full - b) ** 2))
            if sse < best_sse:
                best, best_sse = full, sse
    return best


def _design(system: System, model: Model, counts: dict[int, Traffic]
            ) -> tuple[list[int], np.ndarray, np.ndarray]:
    """The reference's DPU ids, the % communicate one unit of each cost gives each (counts per
    second x the unit in seconds x 100), and the reference's % communicate."""
    if system.reference is None or not system.reference.dpus:
        raise ValueError(f"{system.name}: no reference to fit to")
    ids = sorted(system.reference.dpus)
    a = np.array([[100 * SCALE[c.unit] * sum(getattr(counts[d], f) for f in c.counts) for c in model.costs]
                  for d in ids])
    return ids, a, np.array([system.reference.dpus[d].communicate_pct for d in ids])


def fit(system: System, model: Model, prediction: Prediction | None = None) -> Fit:
    """The model's costs that best reproduce the reference's % communicate, and the three
    columns they give each DPU of the reference."""
    prediction = prediction or predict(system)
    ids, a, target = _design(system, model, traffic(system, prediction))
    values = _nonnegative_lstsq(a, target)
    others = [[i for i in range(len(ids)) if i != k] for k in range(len(ids))]
    left_out = tuple(float(a[k] @ _nonnegative_lstsq(a[o], target[o]) - target[k])
                     for k, o in enumerate(others))
    rows = []
    for d, communicate in zip(ids, a @ values, strict=True):
        compute = prediction.dpu(d).compute_pct or 0.0
        demand = compute + float(communicate)
        # A DPU asked for more than its time falls behind: a run's shares are of the time it took.
        share = 100 / max(demand, 100.0)
        rows.append(Row(d, system.reference.dpus[d], compute * share, float(communicate) * share,
                        max(0.0, 100 - demand), demand,
                        system.dpu(d).minor_cycle_us / 1000 / share))
    return Fit(model, tuple(float(v) for v in values), tuple(rows), left_out)


def fits(system: System) -> dict[str, Fit]:
    """Every model of MODELS fitted to the system's reference."""
    prediction = predict(system)
    return {m.name: fit(system, m, prediction) for m in MODELS}
