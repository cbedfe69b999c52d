"""How far from failure: the largest factor by which an axis of a system can grow before it
shows a fatal flaw (`skel margin`).

The axes an architect changes:
- compute: the computations of one process, of every process of one DPU, or of all of them,
  times the factor (a DPU's or all: its speed divided by the factor, exact; one process: its
  compute time, to the microsecond the wire carries);
- rate: every period divided by the factor together (the paper's 5 -> 2.5 ms experiment,
  made continuous), to the microsecond;
- bytes: every buffer's size times the factor, against its link's bandwidth.

A flaw is what makes a system fail to run as designed: a frame of the cyclic executive that
overflows its minor cycle, a response past its period (exact response-time analysis on the
tasking executive), a link over its bandwidth, a data-wait deadlock. A `sync: data` reader
paced by a slower writer answers past its period by design: its pacing is named, not counted.

`probe` says what flaws a scaled system shows: the prediction (`predicted_flaws`, from the
file alone), or a simulation of it (host/live/simulate.py). Flaws grow with the factor, so a
bisection between the last clean factor and the first flawed one finds the margin; with the
prediction, to a millionth.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..model import System
from .predict import Prediction, predict

AXES = ("compute", "rate", "bytes")
Probe = Callable[[System], list[str]]
MOST = 1000.0            # no flaw up to this factor: the axis does not limit the system
PREDICTED_PRECISION = 1e-6
_EPS_LOAD = 1e-9         # a load of exactly 100 % fits (frames.py's own rounding)


@dataclass(frozen=True)
class Scope:
    """What an axis scales: one process (`process`), one DPU's processes (`dpu`), or all."""

    process: str | None = None
    dpu: int | None = None

    @property
    def name(self) -> str:
        if self.process is not None:
            return f"process {self.process}"
        return f"DPU {self.dpu}" if self.dpu is not None else "all processes"


@dataclass(frozen=True)
class Margin:
    axis: str
    scope: Scope
    factor: float | None         # the largest factor with no flaw; None: none up to MOST
    breaks: tuple[str, ...]      # the flaws just past it (at factor x (1 + precision))
    paced: tuple[str, ...] = ()  # readers paced by a slower writer: their rate is not theirs to set

    def to_json(self) -> dict[str, object]:
        return {"axis": self.axis, "scope": self.scope.name, "factor": self.factor,
                "breaks": list(self.breaks), "paced": list(self.paced)}


def _periods(system: System, factor: float) -> System:
    processes = tuple(dataclasses.replace(p, period_us=max(1, round(p.period_us / factor)))
                      for p in system.processes)
    dpus = []
    for d in system.dpus:
        old = [p.period_us for p in system.processes if p.dpu == d.id]
        new = [p.period_us for p in processes if p.dpu == d.id]
        derived = bool(old) and d.minor_cycle_us == math.gcd(*old)  # no minor cycle given: the gcd again
        minor = math.gcd(*new) if derived else max(1, round(d.minor_cycle_us / factor))
        dpus.append(dataclasses.replace(d, minor_cycle_us=minor))
    return dataclasses.replace(system, processes=processes, dpus=tuple(dpus))


def _compute(system: System, factor: float, scope: Scope) -> System:
    if scope.process is None:  # a DPU's speed divides all its computations: exact
        dpus = tuple(dataclasses.replace(d, speed=d.speed / factor) if scope.dpu in (None, d.id) else d
                     for d in system.dpus)
        return dataclasses.replace(system, dpus=dpus)

    def grown(p):  # type: ignore[no-untyped-def]
        if p.name != scope.process:
            return p
        varying = p.varying and dataclasses.replace(
            p.varying, quantiles_us=tuple(q * factor for q in p.varying.quantiles_us))
        return dataclasses.replace(p, compute_us=round(p.compute_us * factor), varying=varying)
    return dataclasses.replace(system, processes=tuple(grown(p) for p in system.processes))


def scaled(system: System, axis: str, factor: float, scope: Scope = Scope()) -> System:
    """`system` with `axis` grown by `factor` over `scope` (rate and bytes: the whole system)."""
    if axis == "compute":
        out = _compute(system, factor, scope)
    elif axis == "rate":
        out = _periods(system, factor)
    elif axis == "bytes":
        out = dataclasses.replace(system, buffers=tuple(
            dataclasses.replace(b, bytes=max(1, math.ceil(b.bytes * factor))) for b in system.buffers))
    else:
        raise ValueError(f"unknown axis {axis!r}: one of {', '.join(AXES)}")
    return out


def flaws_of(prediction: Prediction) -> list[str]:
    """What in `prediction` keeps the system from running as designed, one line each."""
    out = [f"{e.path}: {e.problem}" for e in prediction.errors]
    for d in prediction.dpus:
        if d.overflowing:
            out.append(f"DPU {d.id}: {len(d.overflowing)} frame(s) overflow its "
                       f"{d.minor_cycle_us / 1000:g} ms minor cycle (load {d.load_pct:.1f} %)")
        elif d.load_pct > 100 + _EPS_LOAD:
            out.append(f"DPU {d.id}: load {d.load_pct:.1f} % over 100 %")
    for p in prediction.processes:
        if p.paced_by is None and not p.schedulable:
            answer = "unbounded" if p.response_us is None else f"{p.response_us / 1000:.3f} ms"
            out.append(f"{p.name} (DPU {p.dpu}): response {answer} past its {p.period_us / 1000:g} ms period")
    out += [f"link {link.name}: {8 * link.known_bytes_per_s / 1e6:.2f} Mbit/s over its "
            f"{link.bandwidth_mbps:g}" for link in prediction.links if link.over]
    return out


def predicted_flaws(system: System) -> list[str]:
    return flaws_of(predict(system))


def _paced(system: System) -> tuple[str, ...]:
    return tuple(f"{p.name} is paced by {p.paced_by}: it runs at the writer's rate, whatever the factor"
                 for p in predict(system).processes if p.paced_by is not None)


def margin(system: System, axis: str, scope: Scope = Scope(), probe: Probe = predicted_flaws,
           precision: float = PREDICTED_PRECISION) -> Margin:
    """The largest factor of `axis` over `scope` at which `probe` finds no flaw (a factor under
    1 when the system is flawed as it is), and what breaks just past it."""
    def flawed(factor: float) -> list[str]:
        return probe(scaled(system, axis, factor, scope))

    lo, hi = 1.0, 1.0
    if flawed(1.0):
        lo = 0.5
        while flawed(lo):
            hi, lo = lo, lo / 2
            if lo < 1 / MOST:
                return Margin(axis, scope, None, tuple(flawed(lo)), _paced(system))
    else:
        hi = 2.0
        while not flawed(hi):
            lo, hi = hi, hi * 2
            if hi > MOST:
                return Margin(axis, scope, None, (), _paced(system))
    while hi - lo > precision * lo:
        mid = (lo + hi) / 2
        if flawed(mid):
            hi = mid
        else:
            lo = mid
    return Margin(axis, scope, lo, tuple(flawed(hi)), _paced(system))


def scopes(system: System, processes: Sequence[str] = (), dpus: Sequence[int] = ()) -> list[Scope]:
    """The scopes asked for, or by default all processes together, then each DPU, then each process."""
    if processes or dpus:
        return [Scope(dpu=d) for d in dpus] + [Scope(process=p) for p in processes]
    return ([Scope()] + [Scope(dpu=d.id) for d in system.dpus]
            + [Scope(process=p.name) for p in system.processes])
