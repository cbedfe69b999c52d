"""One run: push the system, start every DPU at one instant, follow, record, report.

The printed tables come from the recorded log through the same analysis as
`skel report`, so what `skel run` shows is exactly what the log alone gives.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn

import skelmsg
from skeleton.analysis.report import analyze
from skeleton.analysis.tables import print_report
from skeleton.host import spawn
from skeleton.host.control import Control, PushResult
from skeleton.host.system import System

EXIT_OK, EXIT_FAILED, EXIT_BAD_INPUT, EXIT_FATAL_FLAW = 0, 1, 2, 3
START_LEAD_S = 0.5          # time for START to reach every DPU before cycle 0
REPORT_GRACE_S = 5.0        # how long after the end we wait for the DPUs' reports
HEAR_TIMEOUT_S = 5.0
CONFIG_RESEND_S = 1.0


@dataclass
class RunOptions:
    spawn: bool = False
    cycles: int | None = None
    duration_s: float | None = None
    out: Path | None = None
    as_json: bool = False
    compare_paper: bool = False
    # Run the generation `skel push` already applied, when every DPU still has it.
    pushed_generation: int | None = None
    dpu_args: list[str] = field(default_factory=list)


def control_url(system: System) -> str:
    return system.default_link.url


def default_out(system: System) -> Path:
    return Path("runs") / f"{system.name}-{time.strftime('%Y%m%d-%H%M%S')}"


class RunFollower:
    """Watches heartbeats during a run: faults as they happen, when to stop early."""

    def __init__(self, system: System, control: Control, console: Console) -> None:
        self.system = system
        self.control = control
        self.console = console
        self.writer = {b.id: system.process(b.writer) for b in system.buffers}
        self.names = {p.id: p.name for p in system.processes}
        self.lockouts: dict[int, skelmsg.lockout_t] = {}
        self.lost: set[int] = set()
        self.stop_reason: str | None = None

    def poll(self, run_id: int, dpu_ids: list[int]) -> None:
        for view in self.control.snapshot().values():
            if view.status.run_id != run_id:
                continue
            for lockout in view.status.lockouts:
                if lockout.process not in self.lockouts:
                    self.lockouts[lockout.process] = lockout
                    self._announce_lockout(view.status.dpu, lockout)
        for dpu_id in self.control.lost(dpu_ids):
            if dpu_id not in self.lost:
                self.lost.add(dpu_id)
                self.console.print(f"[bold red]FAULT[/] dpu_lost: DPU {dpu_id} stopped answering")
                if "dpu_lost" in self.system.run.stop_on:
                    self.stop_reason = self.stop_reason or f"DPU {dpu_id} lost"

    def _announce_lockout(self, dpu: int, lockout: skelmsg.lockout_t) -> None:
        name = self.names.get(lockout.process, str(lockout.process))
        waits = ""
        if lockout.buffer >= 0:
            writer = self.writer.get(lockout.buffer)
            waits = f", waiting on buffer {lockout.buffer}" + (f" from {writer.name}" if writer else "")
        self.console.print(f"[bold red]FAULT[/] lockout: {name} (DPU {dpu}) at cycle {lockout.cycle}{waits}")
        stop_on = self.system.run.stop_on
        jam = lockout.buffer >= 0 and getattr(self.writer.get(lockout.buffer), "id", None) in self.lockouts
        if "lockout" in stop_on or ("jam" in stop_on and jam):
            self.stop_reason = self.stop_reason or f"lockout of {name}"


def run(system: System, options: RunOptions, console: Console | None = None) -> int:
    console = console or Console()
    out = options.out or default_out(system)
    out.mkdir(parents=True, exist_ok=True)
    (out / "system.yaml").write_text(system.source_text)
    url = control_url(system)
    dpu_ids = sorted(d.id for d in system.dpus)
    daemons = []
    if options.spawn:
        daemons = [spawn.start_dpu(d.id, url, out / "logs", options.dpu_args)
                   for d in system.dpus if spawn.is_local(d.host)]
    logger = spawn.start_logger(url, out / "run.lcm")
    control = Control(url)
    try:
        silent = control.wait_heard(dpu_ids, HEAR_TIMEOUT_S)
        if silent:
            console.print(f"[red]no heartbeat from DPU {', '.join(map(str, silent))} on {url}[/]: "
                          "start them (`skel up FILE` or skel-dpu --id N on their hosts) or use --spawn")
            return EXIT_FAILED
        run_id = time.time_ns() // 1_000_000
        generation = options.pushed_generation
        current = {v.status.generation for i, v in control.snapshot().items() if i in dpu_ids}
        if generation is None or current != {generation}:
            generation = control.next_generation()
            pushed = control.push(system.to_config(generation, run_id, committed=False), dpu_ids)
            if not pushed.ok:
                _print_push_failure(console, pushed)
                return EXIT_FAILED
        duration_ns = system.run_duration_ns(options.cycles, options.duration_s)
        follower = RunFollower(system, control, console)
        committed = system.to_config(generation, run_id, committed=True)
        _follow(control, follower, console, committed, duration_ns, dpu_ids)
        control.wait_for(lambda: all((d, run_id) in control.reports for d in dpu_ids
                                     if d not in follower.lost), REPORT_GRACE_S)
        # The DPUs flush their last timing batches before the report: give the logger a moment.
        time.sleep(0.3)
    finally:
        control.close()
        spawn.stop(logger)
        for daemon in daemons:
            spawn.stop(daemon)
    report = analyze(out / "run.lcm", run_id=run_id)
    (out / "report.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
    if options.as_json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        paper = None
        if options.compare_paper and system.reference is not None:
            paper = {i: row.model_dump() for i, row in system.reference.dpus.items()}
        print_report(report, console=console, paper=paper)
        console.print(f"run written to {out}/ (system.yaml, run.lcm, report.json)")
    fatal = any(f["kind"] in ("lockout", "jam") for f in report.to_json()["faults"])
    return EXIT_FATAL_FLAW if fatal else EXIT_OK


def _follow(control: Control, follower: RunFollower, console: Console, config: skelmsg.config_t,
            duration_ns: int, dpu_ids: list[int]) -> None:
    """Start the run and follow it; re-send the committed config every second meanwhile, so
    a late or restarted DPU catches up and the log holds the configuration of the run."""
    run_id = config.run_id
    control.publish_config(config)
    start_utc = time.time_ns() + int(START_LEAD_S * 1e9)
    control.start(config.generation, run_id, start_utc, duration_ns)
    resent = time.monotonic()
    end_utc = start_utc + duration_ns
    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
               TimeRemainingColumn()]
    with Progress(*columns, console=console, transient=True) as progress:
        task = progress.add_task(f"run {run_id}", total=duration_ns / 1e9)
        while time.time_ns() < end_utc + 200_000_000:
            follower.poll(run_id, dpu_ids)
            if follower.stop_reason:
                console.print(f"stopping early: {follower.stop_reason} (run.stop_on)")
                control.stop()
                break
            progress.update(task, completed=max(0.0, (time.time_ns() - start_utc) / 1e9))
            if time.monotonic() - resent >= CONFIG_RESEND_S:
                control.publish_config(config)
                resent = time.monotonic()
            time.sleep(0.1)
    follower.poll(run_id, dpu_ids)


def _print_push_failure(console: Console, pushed: PushResult) -> None:
    for dpu_id, reason in sorted(pushed.rejected.items()):
        console.print(f"[red]DPU {dpu_id} rejected generation {pushed.generation}[/]: {reason}")
    for dpu_id in pushed.silent:
        console.print(f"[red]DPU {dpu_id} did not answer generation {pushed.generation}[/]")
    console.print("nothing was committed: every DPU keeps its previous configuration")
