"""The prediction beside the measurement: THE definitions of the delta between what the
system file predicts (host/theory/predict.py, handed over as its JSON, `skel check --json`'s
`prediction`) and what a run measured, and of a measured value outside its prediction.

The prediction counts only the file's computations and schedule, so what a run measures
beyond it is the platform's own cost: communication, wake-up, interference. The
tolerances say how much of that cost passes unremarked:
- % compute per DPU: within COMPUTE_POINTS either way (sleep mode measures SERVO to 0.03),
  measured over the time the platform let the DPU run (DpuMetrics.compute_unstalled_pct): the
  prediction is for a dedicated CPU, and the stalls are the platform's, reported as such;
- % communicate per DPU, where its links charge costs (the prediction's is theirs alone): no
  more than COMPUTE_POINTS below it (the platform's communication only adds);
- new / stale share of a reader's cycles and dropped sequences per cycle: within SHARE
  either way (they follow from the two rates alone);
- response (release -> end of work) per process and chain latency: the measured p99 may
  exceed the predicted worst by late_pct (the system file's own lateness tolerance) of the
  process's period, of the tail's for a chain; below the worst is what a bound allows. A
  data reader paced by a slower writer waits for it in every response: not compared.
A figure the prediction leaves unknown (None: it follows from how often the host sends an
event, which no file says) is never compared: what a run measures there is no one's cost.
A run whose faults name a cause the prediction leaves out (a DPU lost, the design's own
fatal fault) puts a figure outside its prediction down to that, not to the platform.
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

from skeleton.host.model import Expected

from .chains import ChainMetrics
from .faults import Fault
from .latency import BufferMetrics, ReaderMetrics
from .metrics import DpuMetrics, InputMetrics, ProcessMetrics

COMPUTE_POINTS = 2.0
SHARE = 0.05
PLATFORM = "the platform's own cost (communication, wake-up, interference)"
# A simulated run has no platform: what it puts outside the prediction is the prediction's own.
SIMPLIFIED = "the prediction's own simplifications (a simulated run has no platform)"
WORST = "the predicted worst"
# A process running real code computes what its code takes, not the compute_us the prediction assumes.
REAL_CODE = "the real code's own compute times, not the compute_us the prediction assumes"
# The prediction counts a link's emulated loss, not what it does to a data reader's wait.
LOSSES = "or the links' emulated losses (a data reader waits on for the buffer after a lost one)"

# The system file a config carries -> what its prediction expects; raises ValueError (one line:
# why) when that file cannot be predicted here (a samples file left behind, say).
Predictor = Callable[[str], Expected]


@dataclass
class Beside:
    """One figure: predicted, measured, delta = measured - predicted, and whether the
    measured value is outside its prediction by more than the tolerance."""

    predicted: float | None
    measured: float | None
    delta: float | None = None
    outside: bool = False


def _none() -> Beside:
    """No emulated transport: nothing modelled, nothing measured beside it."""
    return Beside(0.0, None)


@dataclass
class DpuBeside:
    id: int
    compute_pct: Beside
    communicate_pct: Beside = field(default_factory=lambda: Beside(None, None))  # the links' charged costs


@dataclass
class ProcessBeside:
    name: str
    dpu: int
    response_us: Beside  # predicted worst (None: unbounded) beside the measured p99
    response_max_us: float | None
    paced_by: str | None  # a paced data reader: its response holds its wait, not compared


@dataclass
class InputBeside:
    reader: str
    buffer: str
    writer: str
    new: Beside  # share of the reader's cycles
    stale: Beside
    dropped: Beside  # sequences per reader cycle
    # The link's emulated transport, not judged (a real run adds the platform's own transport):
    transport_us: Beside = field(default_factory=_none)  # its mean delay beside the measured p50 transport
    lost_pct: Beside = field(default_factory=_none)  # % of the writer's buffers lost beside the measured


@dataclass
class ChainBeside:
    name: str
    best_us: float
    latency_us: Beside  # predicted worst (None: unbounded) beside the measured p99
    latency_max_us: float | None
    # Of its latency, the network's, not judged: the links' mean emulated delays beside the sum of its
    # buffers' measured p50 transport, each to the step that reads it.
    network_us: Beside = field(default_factory=_none)  # links' mean delays beside its buffers' transport


@dataclass
class Predicted:
    """A run's report generation beside the prediction of its system file."""

    generation: int
    compute_points: float
    share: float
    late_pct: int  # response and chain latency: margin in % of the period
    dpus: list[DpuBeside] = field(default_factory=list)
    processes: list[ProcessBeside] = field(default_factory=list)
    inputs: list[InputBeside] = field(default_factory=list)
    chains: list[ChainBeside] = field(default_factory=list)
    outside: list[str] = field(default_factory=list)  # one line per figure outside its prediction
    cause: str = PLATFORM  # what a figure outside its prediction is put down to (cause_of)


def _plain(predicted: float, measured: float | None) -> Beside:
    """Side by side, never judged."""
    return Beside(predicted, measured, None if measured is None else measured - predicted)


def either_way(predicted: float | None, measured: float | None, tolerance: float) -> Beside:
    if predicted is None or measured is None:
        return Beside(predicted, measured)
    delta = measured - predicted
    return Beside(predicted, measured, delta, abs(delta) > tolerance)


def above_worst(worst: float | None, measured: float | None, margin: float) -> Beside:
    if worst is None or measured is None:
        return Beside(worst, measured)
    delta = measured - worst
    return Beside(worst, measured, delta, delta > margin)


def at_least(predicted: float | None, measured: float | None, tolerance: float) -> Beside:
    if predicted is None or measured is None:
        return Beside(predicted, measured)
    delta = measured - predicted
    return Beside(predicted, measured, delta, delta < -tolerance)


def input_shares(metrics: InputMetrics) -> tuple[float, float, float] | None:
    """(new, stale, dropped) per cycle of the reader: None before its first cycle."""
    cycles = metrics.new + metrics.stale
    if cycles == 0:
        return None
    return metrics.new / cycles, metrics.stale / cycles, metrics.dropped / cycles


def cause_of(faults: Sequence[Fault]) -> str:
    """What the figures outside their prediction are put down to: the platform's own cost,
    unless the run's faults name what the prediction leaves out and the platform did not do."""
    lost = sorted({f.dpu for f in faults if f.kind == "dpu_lost" and f.dpu is not None})
    if lost:
        return f"DPU {', '.join(map(str, lost))} lost during the run (its fault above), not only the platform"
    if any(f.fatal for f in faults):
        return "the design's own fatal faults above, not only the platform"
    return PLATFORM


def _measured(buffers: Sequence[BufferMetrics]) -> dict[tuple[str, str], tuple[BufferMetrics, ReaderMetrics]]:
    return {(r.process, b.buffer): (b, r) for b in buffers for r in b.readers}


def _network(prediction: Expected, chain_processes: tuple[str, ...],
             transports: dict[tuple[str, str], tuple[BufferMetrics, ReaderMetrics]]) -> float | None:
    """The sum of the measured p50 transport of a chain's buffers, each at the step that reads it."""
    total = 0.0
    for before, after in itertools.pairwise(chain_processes):
        i = next((i for i in prediction.inputs if i.reader == after and i.writer == before), None)
        found = transports.get((after, i.buffer)) if i else None
        if found is None or found[1].latency_us.p50 is None:
            return None
        total += found[1].latency_us.p50
    return total


def beside(prediction: Expected, generation: int, late_pct: int, dpus: list[DpuMetrics],
           processes: list[ProcessMetrics], chains: list[ChainMetrics],
           faults: Sequence[Fault] = (), buffers: Sequence[BufferMetrics] = ()) -> Predicted:
    """The measured figures of one generation (the report's, whose `faults` say what to put
    a figure outside its prediction down to) beside `prediction`, matched by DPU id, process
    name, (reader, buffer) and chain name; what either side lacks is left out."""
    out = Predicted(generation, COMPUTE_POINTS, SHARE, late_pct, cause=cause_of(faults))
    if any(i.lost_pct > 0 for i in prediction.inputs):
        out.cause += f"; {LOSSES}"
    transports = _measured(buffers)
    measured_dpus = {d.id: d for d in dpus}
    for d in prediction.dpus:
        if (m := measured_dpus.get(d.id)) is not None:
            compute = either_way(d.compute_pct, m.compute_unstalled_pct, COMPUTE_POINTS)
            charged = d.communicate_pct or None  # no cost charged: nothing to compare
            out.dpus.append(DpuBeside(d.id, compute, at_least(charged, m.communicate_pct, COMPUTE_POINTS)))
    by_name = {p.name: p for p in processes}
    for p in prediction.processes:
        if (mp := by_name.get(p.name)) is None:
            continue
        margin = mp.period_us * late_pct / 100
        response = above_worst(p.response_us, mp.response_us.p99, math.inf if p.paced_by else margin)
        out.processes.append(ProcessBeside(p.name, mp.dpu, response, mp.response_us.max, p.paced_by))
    for i in prediction.inputs:
        reader = by_name.get(i.reader)
        found = next((m for m in reader.inputs if m.buffer == i.buffer), None) if reader else None
        shares = input_shares(found) if found else None
        if shares is None:
            continue
        new, stale, dropped = (either_way(want, got, SHARE)
                               for want, got in zip((i.new, i.stale, i.dropped), shares, strict=True))
        b, r = transports.get((i.reader, i.buffer), (None, None))
        transport = _plain(i.transport_us, r.latency_us.p50 if r is not None else None)
        measured = b is not None and r is not None and b.published > 0
        lost = _plain(i.lost_pct, 100 * r.lost / b.published if measured else None)
        out.inputs.append(InputBeside(i.reader, i.buffer, i.writer, new, stale, dropped, transport, lost))
    measured_chains = {c.name: c for c in chains}
    for c in prediction.chains:
        mc, tail = measured_chains.get(c.name), by_name.get(c.processes[-1])
        if mc is None or tail is None:
            continue
        latency = above_worst(c.worst_us, mc.latency_us.p99, tail.period_us * late_pct / 100)
        network = _plain(c.network_us, _network(prediction, c.processes, transports))
        out.chains.append(ChainBeside(c.name, c.best_us, latency, mc.latency_us.max, network))
    out.outside = _outside_lines(out)
    return out


def _outside_lines(p: Predicted) -> list[str]:
    lines = [f"DPU {d.id}: % compute {_said(p, d.compute_pct, 1, '', f'±{p.compute_points:g} points')}"
             for d in p.dpus if d.compute_pct.outside]
    below = f"-{p.compute_points:g} points"
    lines += [f"DPU {d.id}: % communicate {_said(p, d.communicate_pct, 1, '', below)}"
              for d in p.dpus if d.communicate_pct.outside]
    margin = f"late_pct ({p.late_pct} %) of the period"
    lines += [f"{r.name} (DPU {r.dpu}): response p99 {_said(p, r.response_us, 0, ' µs', margin, WORST)}"
              for r in p.processes if r.response_us.outside]
    for i in p.inputs:  # the stale share is 1 - the new one: outside when that is
        lines += [f"{i.reader} <- {i.buffer}: {what} {_said(p, b, 3, '', f'±{p.share:g}')}"
                  for what, b in (("new share", i.new), ("dropped per cycle", i.dropped)) if b.outside]
    margin = f"late_pct ({p.late_pct} %) of the tail's period"
    lines += [f"chain {c.name}: latency p99 {_said(p, c.latency_us, 0, ' µs', margin, WORST)}"
              for c in p.chains if c.latency_us.outside]
    return lines


def _said(p: Predicted, b: Beside, digits: int, unit: str, tolerance: str,
          predicted: str = "predicted") -> str:
    return (f"{b.measured:.{digits}f}{unit} measured against {predicted} {b.predicted:.{digits}f}{unit} "
            f"({b.delta:+.{digits}f}{unit}, beyond {tolerance}): {p.cause}")
