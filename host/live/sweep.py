"""`skel margin --measure`: the margin measured on the real DPUs, in one run, restarting nothing.

The run starts on the system scaled by the first step's factor; each next step is a live push
(the same two-phase commit as `skel push`), so every DPU switches generation at one boundary
of the grid they share, and holds for HOLD_HYPERPERIODS of that grid (at least MIN_HOLD_S).
The steps are factors of the predicted margin, STEPS, closer together near it. The sweep ends
at the first step whose heartbeats show a lockout, or overruns in more than OVERRUN_SHARE of
its cycles that its window in the log so far confirms (not the platform's stalls); then the
run is stopped, and the one log holds every step, a generation each
(`skel report` shows the sweep: a window per generation).

The verdict of each step is then the log's, window by window: a step is flawed by a fatal
fault, or by overruns in more than OVERRUN_SHARE of a process's cycles that the platform's
stalls do not explain (metrics.overruns_stalled). The measured margin is the last step
before the first flawed one.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console

from skeleton.analysis.errors import SkelError
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.measure.simulated import simulation_beside
from skeleton.analysis.measure.windows import WindowReport
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.views.summary import fault_line

from ..model import System
from ..theory.margin import Scope, scaled
from . import spawn
from .control import Control
from .outcome import HEAR_TIMEOUT_S, START_LEAD_S, control_url
from .repair import LoggerKeeper
from .run import claim, finish, wait_nonempty
from .simulate import simulate_into
from .wire import config_message

STEPS = (0.8, 0.9, 0.95, 0.98, 0.99, 1.0, 1.01, 1.02, 1.05, 1.1)  # x the predicted margin
HOLD_HYPERPERIODS = 2
MIN_HOLD_S = 1.0
OVERRUN_SHARE = 0.02
PUSH_LEAD_MS = 300.0
GRID_MAX_S = 5.0           # a grid longer than this is not waited for whole (contract.MAX_COMMON_US)
LOGGER_READY_S = 2.0


@dataclass
class Step:
    factor: float
    generation: int
    heard: str | None = None     # what the heartbeats said ended the sweep here
    flaw: str | None = None      # what the log's window of this step shows (None: clean)
    compute_pct: dict[int, float] = field(default_factory=dict)  # its window's % compute per DPU
    # the flawed step: its flawed DPU's largest cost against a simulation of the step
    # (analysis/measure/simulated.py: communication, wake-up or interference)
    platform: str | None = None


@dataclass
class Sweep:
    out: Path
    steps: list[Step]

    @property
    def margin(self) -> float | None:
        """The last factor before the first flawed step (None: the first step was flawed)."""
        last = None
        for step in self.steps:
            if step.flaw is not None:
                return last
            last = step.factor
        return last


def hold_s(system: System, hyperperiods: int = HOLD_HYPERPERIODS) -> float:
    grid_us = math.lcm(*(d.minor_cycle_us for d in system.dpus))
    return max(MIN_HOLD_S, hyperperiods * min(grid_us / 1e6, GRID_MAX_S))


def _totals(control: Control, dpu_ids: list[int], run_id: int) -> tuple[int, int, int]:
    """Overruns, minor cycles and lockouts the DPUs' last heartbeats count in run `run_id`."""
    views = [v for i, v in control.snapshot().items() if i in dpu_ids and v.status.run_id == run_id]
    return (sum(v.status.overruns for v in views), sum(v.status.minor_cycles for v in views),
            sum(v.status.nlockouts for v in views))


def _window_flaw(window: WindowReport) -> str | None:
    fatal = [f for f in window.faults if f.fatal]
    if fatal:
        return fault_line(fatal[0])
    for p in window.processes:
        unexplained = p.overruns - p.overruns_stalled
        if p.cycles and unexplained > OVERRUN_SHARE * p.cycles:
            return (f"{p.name} (DPU {p.dpu}): {unexplained} of {p.cycles} cycles overran, no stall "
                    "explains them")
    return None


def _flawed_so_far(out: Path, run_id: int, generation: int) -> bool:
    """Whether the log recorded so far shows generation `generation`'s window flawed."""
    try:
        windows = load_run(out / "run.lcm", run_id=run_id).report.windows
    except LogError:
        return True  # nothing to judge by: the heartbeats' count stands
    return any(w.generation == generation and _window_flaw(w) is not None for w in windows)


def measure(system: System, scope: Scope, predicted: float, out: Path, console: Console,
            spawn_dpus: bool = False, key: bytes | None = None,
            hyperperiods: int = HOLD_HYPERPERIODS) -> Sweep:
    out.mkdir(parents=True, exist_ok=True)
    (out / "system.yaml").write_text(system.source_text)
    url = control_url(system)
    dpu_ids = sorted(d.id for d in system.dpus)
    factors = [predicted * s for s in STEPS]
    hold = hold_s(system, hyperperiods)
    warmup_s = system.run.warmup_cycles * max(p.period_us for p in system.processes) / 1e6
    duration_ns = round((warmup_s + len(factors) * (hold + PUSH_LEAD_MS / 1e3 + GRID_MAX_S) + 1) * 1e9)
    control = Control(url, key)
    daemons: list[spawn.Daemon] = []
    keeper = None
    steps: list[Step] = []
    run_id = time.time_ns() // 1_000_000
    try:
        if spawn_dpus:
            daemons = [spawn.start_dpu(d.id, url, out / "logs", [], deadline_s=duration_ns / 1e9 + 60)
                       for d in system.dpus if spawn.is_local(d.host)]
        silent = control.wait_heard(dpu_ids, HEAR_TIMEOUT_S,
                                    introduce=lambda g: config_message(system, g, 0, committed=False))
        if silent or not claim(control, dpu_ids, False, console):
            raise SweepError(f"no heartbeat from DPU {', '.join(map(str, silent))} on {url}: start them "
                             "(`skel up FILE`) or use --spawn" if silent else "the DPUs are busy")
        generation = control.next_generation()
        first = config_message(scaled(system, "compute", factors[0], scope), generation, run_id,
                               committed=False)
        if not control.push(first, dpu_ids).ok:
            raise SweepError(f"the DPUs refused the first step's configuration (generation {generation})")
        keeper = LoggerKeeper(control.listen_url, out / "run.lcm", duration_ns / 1e9 + 30, say=console.print)
        wait_nonempty(out / "run.lcm", LOGGER_READY_S)
        control.follow(run_id)
        first.committed = 1
        control.publish_config(first)
        control.start(generation, run_id, time.time_ns() + int(START_LEAD_S * 1e9), duration_ns)
        time.sleep(START_LEAD_S + warmup_s)  # the first step is measured past the run's warm-up
        steps.append(Step(factors[0], generation))
        for factor in [*factors[1:], None]:
            before = _totals(control, dpu_ids, run_id)
            time.sleep(hold)
            after = _totals(control, dpu_ids, run_id)
            overran, cycles = after[0] - before[0], after[1] - before[1]
            locked = after[2] > before[2]
            # Overruns the heartbeats count may be the platform's: the log so far judges them as
            # the step's window will be judged (a lockout ends the sweep at once).
            if locked or (cycles and overran > OVERRUN_SHARE * cycles and _flawed_so_far(out, run_id,
                                                                                         generation)):
                steps[-1].heard = (f"{after[2] - before[2]} lockout(s)" if locked
                                   else f"{overran} of {cycles} minor cycles overran")
                console.print(f"x{steps[-1].factor:.4f}: {steps[-1].heard}: the sweep ends here")
                break
            console.print(f"x{steps[-1].factor:.4f}: held {hold:.1f} s, {overran} of {cycles} minor cycles "
                          "overran")
            if factor is None:
                break
            generation += 1
            pushed = control.push(config_message(scaled(system, "compute", factor, scope), generation, run_id,
                                                 committed=False), dpu_ids, at_ms=PUSH_LEAD_MS)
            if not pushed.ok:
                raise SweepError(f"the push of x{factor:.4f} (generation {generation}) did not take")
            steps.append(Step(factor, generation))
        control.stop()
        finish(control, run_id, dpu_ids, console)
    finally:
        control.close()
        if keeper is not None:
            keeper.stop()
        for daemon in daemons:
            spawn.stop(daemon)
    windows = {w.generation: w for w in load_run(out / "run.lcm", run_id=run_id).report.windows}
    for step in steps:
        window = windows.get(step.generation)
        step.flaw = "no window measured" if window is None else _window_flaw(window)
        if window is not None:
            step.compute_pct = {d.id: d.compute_pct for d in window.dpus if d.compute_pct is not None}
    flawed = next((s for s in steps if s.flaw is not None), None)
    if flawed is not None and flawed.generation in windows:
        flawed.platform = _platform(system, scope, flawed, windows[flawed.generation], out)
    return Sweep(out, steps)


def _platform(system: System, scope: Scope, step: Step, window: WindowReport, out: Path) -> str | None:
    """What the platform cost the flawed step's DPUs beyond a simulation of the same step."""
    at = out / f"simulated-g{step.generation}"
    try:
        simulated = simulate_into(scaled(system, "compute", step.factor, scope), at,
                                  round(hold_s(system) * 4e9))[1].report.dpus
    except (SkelError, OSError) as error:
        return f"no simulation of the step: {error}"
    named = [f"DPU {c.id}: {c.named} {c.cost_points:+.1f} points" for c in
             simulation_beside(window.dpus, simulated, str(at)).dpus if c.named]
    return "; ".join(named) or "within half a point of its simulation on every DPU"


class SweepError(SkelError, RuntimeError):
    """The sweep could not run; the message says why."""
