"""The simulation beside the measurement: THE definitions of what a measured run costs the
platform, per DPU.

A simulated run (`skel simulate`, skel-dpu on virtual time) is the executives' own logic on
an ideal machine: every cycle starts at its release, a buffer arrives as it is sent, nothing
stalls. The same system measured on the real machines differs from it by the platform alone.
Per DPU, in points of its time (measured - simulated):
- communication: % communicate, what reading and writing the buffers cost;
- wake-up: how late the cycles started (the median release latency over the cycle time);
- interference: what the platform took from the DPU's own time (% overhead and stalls).
The largest of the three names the DPU's delta when it exceeds NAMED_POINTS; below that the
DPU ran as simulated.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from .metrics import DpuMetrics

NAMED_POINTS = 0.5
COMMUNICATION, WAKE_UP, INTERFERENCE = "communication", "wake-up", "interference"


@dataclass
class DpuPlatform:
    """One DPU: the simulated figures, the measured ones, and what the platform cost."""

    id: int
    simulated_compute_pct: float | None
    simulated_communicate_pct: float | None
    simulated_wait_pct: float | None
    compute_points: float | None  # measured - simulated % compute
    costs: dict[str, float] = field(default_factory=dict)  # points of the DPU's time, by kind
    named: str | None = None  # the largest cost beyond NAMED_POINTS; None: ran as simulated

    @property
    def cost_points(self) -> float:
        return self.costs.get(self.named, 0.0) if self.named else 0.0


@dataclass
class Simulation:
    """A simulation of the report generation's system beside a measured run."""

    where: str  # the simulated run's directory or log
    dpus: list[DpuPlatform] = field(default_factory=list)


def _minus(a: float | None, b: float | None) -> float | None:
    return None if a is None or b is None else a - b


def platform_cost(measured: DpuMetrics, simulated: DpuMetrics) -> DpuPlatform:
    costs: dict[str, float] = {}
    comm = _minus(measured.communicate_pct, simulated.communicate_pct)
    if comm is not None:
        costs[COMMUNICATION] = comm
    latency, cycle_ms = measured.release_latency_us.p50, measured.measured_cycle_ms
    if latency is not None and cycle_ms:
        costs[WAKE_UP] = 100.0 * (latency - (simulated.release_latency_us.p50 or 0.0)) / 1000.0 / cycle_ms
    overhead = _minus(measured.overhead_pct, simulated.overhead_pct)
    if overhead is not None:
        costs[INTERFERENCE] = overhead + (measured.stall_pct or 0.0)
    worst = max(costs, key=lambda k: costs[k], default=None)
    named = worst if worst is not None and costs[worst] > NAMED_POINTS else None
    return DpuPlatform(measured.id, simulated.compute_pct, simulated.communicate_pct, simulated.wait_pct,
                       _minus(measured.compute_pct, simulated.compute_pct), costs, named)


def simulation_beside(measured: list[DpuMetrics], simulated: list[DpuMetrics], where: str) -> Simulation:
    """The measured DPUs beside the simulated ones, matched by id; a DPU either lacks is left out."""
    by_id = {d.id: d for d in simulated}
    return Simulation(where, [platform_cost(d, by_id[d.id]) for d in measured if d.id in by_id])
