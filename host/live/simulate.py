"""`skel simulate`: the whole system on virtual time, on this machine, in seconds.

The host tool writes what it would publish for a run (the committed config, then START)
into an input log, each message at a virtual instant; `skel-dpu --simulate` runs every
DPU's own executive on virtual time in one process and writes the log a run's logger
would have written; the same analysis as `skel run` reports it. Nothing of the machine
enters it: no clock, no network, no platform stall. So the same file and seed give the
same log and report, byte for byte, and what a simulated run shows is the executives'
logic alone: predicted -> simulated is the analysis's own pessimism or error, simulated
-> measured the platform's cost.

A push during the run (`--push S:FILE`, as `skel push` would do it S seconds into the run)
is staged, then committed for that instant: every DPU switches at the first boundary of
the grid they share from then, without a restart, as on the real machines.

A run's `stop_on` is honoured as `skel run` honours it: the simulation is run again with
a STOP where `skel run` would have sent it (one fault window after the first such fault),
which on virtual time changes nothing before that instant.
"""

from __future__ import annotations

import dataclasses
import subprocess
import tempfile
import time
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import lcm
from rich.console import Console

import skelmsg
from skeleton.analysis.errors import EXIT_FAILED, SkelError
from skeleton.analysis.measure.report import RunReport
from skeleton.analysis.measure.run import RunAnalysis, load_run
from skeleton.analysis.read.messages import LogError
from skeleton.analysis.views.summary import fault_line
from skelmsg import contract

from ..model import System
from ..theory.predict import predict
from .outcome import START_LEAD_S, RunOptions, control_url, fault_window_s, report_run
from .repair import RepairResult
from .spawn import SpawnError, dpu_binary
from .wire import config_message

# A simulated run's clock: UTC starts at 2000-01-01T00:00:00Z, fixed, so that nothing in its
# log or report depends on when it was made.
SIM_EPOCH_UTC_NS = 946_684_800 * 1_000_000_000
SIM_RUN_ID = 1
SIM_GENERATION = 1
SIM_SESSION = 1
# The input's messages, as `skel run` sends them: the config, then START a lead later.
_COMMAND_AFTER_NS = 1_000_000


@dataclass(frozen=True)
class Push:
    """A `skel push` of `system` during the run, committed for `at_s` after its start."""

    at_s: float
    system: System


# A push is staged and committed just before its instant, as `skel push --at-ms` leads it.
_STAGE_BEFORE_NS = 2_000_000


@dataclass(frozen=True)
class Simulated:
    """What one simulation took: virtual seconds, and the wall seconds they cost."""

    virtual_s: float
    wall_s: float

    @property
    def speed(self) -> float:
        return self.virtual_s / self.wall_s if self.wall_s > 0 else float("inf")


class SimulationError(SkelError, RuntimeError):
    """skel-dpu --simulate failed; the message names its log."""


def _command(kind: int, seq: int, **fields: int) -> bytes:
    cmd = skelmsg.command_t()
    cmd.seq, cmd.kind, cmd.dpu = seq, kind, -1
    cmd.session, cmd.force, cmd.sender = SIM_SESSION, 0, contract.SIMULATED_SENDER
    for name, value in fields.items():
        setattr(cmd, name, value)
    return cmd.encode()


def write_input(system: System, path: Path, duration_ns: int, pushes: Sequence[Push] = (),
                stop_at_ns: int | None = None) -> None:
    """The host's side of a run, as messages at virtual instants (µs, UTC): the committed
    config at the epoch, START one START_LEAD_S later, each push staged and committed for its
    instant, and a STOP `stop_at_ns` after START."""
    config = config_message(system, SIM_GENERATION, SIM_RUN_ID, committed=True)
    config.session, config.force, config.sender = SIM_SESSION, 0, contract.SIMULATED_SENDER
    config.sent_utc_ns = SIM_EPOCH_UTC_NS
    start_utc_ns = SIM_EPOCH_UTC_NS + round(START_LEAD_S * 1e9)
    messages = [(SIM_EPOCH_UTC_NS, contract.CONFIG_CHANNEL, config.encode()),
                (SIM_EPOCH_UTC_NS + _COMMAND_AFTER_NS, contract.COMMAND_CHANNEL,
                 _command(skelmsg.command_t.START, 1, generation=SIM_GENERATION, run_id=SIM_RUN_ID,
                          at_utc_ns=start_utc_ns, duration_ns=duration_ns))]
    for n, push in enumerate(sorted(pushes, key=lambda p: p.at_s)):
        generation, at_ns = SIM_GENERATION + 1 + n, start_utc_ns + round(push.at_s * 1e9)
        staged = config_message(push.system, generation, SIM_RUN_ID, committed=False)
        staged.session, staged.force, staged.sender = SIM_SESSION, 0, contract.SIMULATED_SENDER
        staged.sent_utc_ns = at_ns - _STAGE_BEFORE_NS
        messages.append((at_ns - _STAGE_BEFORE_NS, contract.CONFIG_CHANNEL, staged.encode()))
        messages.append((at_ns - _STAGE_BEFORE_NS // 2, contract.COMMAND_CHANNEL,
                         _command(skelmsg.command_t.COMMIT, 2 + n, generation=generation, at_utc_ns=at_ns)))
    if stop_at_ns is not None:
        messages.append((start_utc_ns + stop_at_ns, contract.COMMAND_CHANNEL,
                         _command(skelmsg.command_t.STOP, 2 + len(pushes))))
    log = lcm.EventLog(str(path), "w", overwrite=True)
    try:
        for at_ns, channel, data in sorted(messages, key=lambda m: m[0]):
            log.write_event(at_ns // 1000, channel, data)
    finally:
        log.close()


def run_simulation(system: System, out: Path, duration_ns: int, pushes: Sequence[Push] = (),
                   stop_at_ns: int | None = None) -> Simulated:
    """Writes out/run.lcm; the simulation's own lines go to out/logs/simulate.log."""
    (out / "logs").mkdir(parents=True, exist_ok=True)
    given = out / "logs" / "input.lcm"
    write_input(system, given, duration_ns, pushes, stop_at_ns)
    began = time.perf_counter()
    with open(out / "logs" / "simulate.log", "wb") as lines:
        done = subprocess.run([str(dpu_binary()), "--simulate", str(given), str(out / "run.lcm"),
                               "--url", control_url(system)], stdout=lines, stderr=subprocess.STDOUT,
                              check=False)
    wall_s = time.perf_counter() - began
    if done.returncode != 0:
        said = out / "logs" / "simulate.log"
        raise SimulationError(f"the simulation failed (exit {done.returncode}): see {said}")
    return Simulated(virtual_s=(START_LEAD_S * 1e9 + duration_ns) / 1e9, wall_s=wall_s)


def beside_run(system: System, out: Path, duration_ns: int) -> tuple[RunAnalysis | None, str | None]:
    """The simulation `skel run` lays beside a measured run (in `out`/simulated), analysed, or
    why none."""
    try:
        return simulate_into(system, out / "simulated", duration_ns)[1], None
    except (SimulationError, SpawnError, OSError, LogError) as error:
        return None, f"no simulation beside the run: {error}"


def _stop_after_ns(system: System, report: RunReport) -> int | None:
    """Where `skel run` would have stopped the run of `report` (ns after its start), None:
    nowhere."""
    if not system.run.stop_on:
        return None
    first = min((f.at_s for f in report.faults if f.kind in system.run.stop_on), default=None)
    if first is None:
        return None
    return round((first + fault_window_s(system)) * 1e9)


def simulate_into(system: System, out: Path, duration_ns: int,
                  pushes: Sequence[Push] = ()) -> tuple[Simulated, RunAnalysis]:
    """A simulated run of `system` in `out` (system.yaml, run.lcm, logs/), stopped where
    `skel run` would stop it, and its log analysed once (every caller reads its report);
    raises SimulationError, OSError or LogError."""
    out.mkdir(parents=True, exist_ok=True)
    (out / "system.yaml").write_text(system.source_text)
    for n, push in enumerate(sorted(pushes, key=lambda p: p.at_s)):  # as `skel run` keeps a push's file
        (out / f"system-g{SIM_GENERATION + 1 + n}.yaml").write_text(push.system.source_text)
    took = run_simulation(system, out, duration_ns, pushes)
    analysis = load_run(out / "run.lcm")
    stop = _stop_after_ns(system, analysis.report)
    if stop is not None and stop < duration_ns:
        took = run_simulation(system, out, duration_ns, pushes, stop_at_ns=stop)
        analysis = load_run(out / "run.lcm")
    return took, analysis


def simulate(system: System, options: RunOptions, console: Console, pushes: Sequence[Push] = ()) -> int:
    out = options.out or Path("runs") / f"{system.name}-sim-{time.strftime('%Y%m%d-%H%M%S')}"
    duration_ns = system.run_duration_ns(options.cycles, options.duration_s)
    try:
        took, analysis = simulate_into(system, out, duration_ns, pushes)
    except (SimulationError, SpawnError, OSError, LogError) as error:
        console.print(f"[red]{error}[/]", soft_wrap=True)
        return EXIT_FAILED
    code = report_run(console, system, options, out, SIM_RUN_ID, set(), RepairResult(), analysis=analysis)
    if not options.as_json:
        console.print(f"simulated {took.virtual_s:.1f} s of system time in {took.wall_s:.2f} s "
                      f"({took.speed:.0f} times real time), on virtual time: no platform in it",
                      highlight=False)
    return code


# A margin probe (host/theory/margin.py) simulates this many cycles of the slowest period past
# a short warm-up: an overload overruns within a frame or two, an RTA miss within a hyperperiod
# of the DPU's own.
PROBE_WARMUP_CYCLES = 2
PROBE_CYCLES = 20


def simulated_flaws(system: System) -> list[str]:
    """The flaws a short simulation of `system` shows: its fatal faults, and any overrun or
    skipped release (on virtual time no platform explains one), but a paced reader's, which
    overruns by design."""
    paced = {p.name for p in predict(system).processes if p.paced_by is not None}
    probe = dataclasses.replace(system, run=dataclasses.replace(system.run, warmup_cycles=PROBE_WARMUP_CYCLES,
                                                                stop_on=()))
    slowest_ns = max(p.period_us for p in system.processes) * 1000
    with tempfile.TemporaryDirectory(prefix="skel-margin-") as tmp:
        _, analysis = simulate_into(probe, Path(tmp), (PROBE_WARMUP_CYCLES + PROBE_CYCLES) * slowest_ns)
        faults = analysis.report.faults
    return [fault_line(f) for f in faults
            if (f.fatal or f.kind in ("overrun", "skipping")) and f.process not in paced]
