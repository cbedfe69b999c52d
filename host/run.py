"""One run: push the system, start every DPU at one instant, follow, record, report.

The printed tables come from the recorded log through the same analysis as
`skel report`, so what `skel run` shows is exactly what the log alone gives.

What outlives the host tool: the DPUs have the run's duration, so they finish
their cycles if `skel run` dies. The logger is started (once the push has
succeeded) in its own session under `timeout`: a killed host tool neither takes
it down nor leaves it running for ever; it stops by itself about
REPORT_GRACE_S + REPAIR_LIMIT_S + LOGGER_MARGIN_S (~20 s) after the run's planned end. On a
clean end it is stopped once the log holds everything the DPUs published: what
the logger missed is asked for again (repair.py), during the run and after the
reports. DPUs started with --spawn end the same way.

A `skel push` during the run (from any host) is followed: when the DPUs' heartbeats
show a newer generation applied, the config of that generation, heard on
SKEL_CONFIG when it was staged, replaces ours in the periodic re-send. No state
file is shared, so the push may come from another machine than the run.
"""

from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

import skelmsg
from skeleton.analysis.exitcodes import EXIT_FAILED, EXIT_FATAL_FLAW, EXIT_INTERRUPTED, EXIT_OK
from skeleton.analysis.metrics import utilization_pct
from skeleton.analysis.report import LogError, analyze
from skeleton.analysis.tables import print_report
from skeleton.host import spawn
from skeleton.host.check import warmup_warnings
from skeleton.host.clock import ClockKeeper
from skeleton.host.control import Control, PushResult
from skeleton.host.repair import LogRepair, RepairResult
from skeleton.host.system import System

START_LEAD_S = 0.5          # time for START to reach every DPU before cycle 0
REPORT_GRACE_S = 5.0        # how long after the end we wait for the DPUs' reports
HEAR_TIMEOUT_S = 5.0
CONFIG_RESEND_S = 1.0
POLL_S = 0.1                # follower period: a lost DPU is reported within LOST_AFTER_S + this
PUSH_TIMEOUT_S = 3.0        # per phase (stage, commit) of Control.push
LOGGER_MARGIN_S = 5.0       # an orphaned logger ends this long after the report grace
LOGGER_READY_S = 2.0        # heartbeats come at 5 Hz: the logger has one well within this
REPAIR_STUCK_S = 3.0        # after the reports, the repair of the log gives up this long without progress
REPAIR_LIMIT_S = 10.0       # ... or after this long in all
FATAL_KINDS = ("lockout", "jam")


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
    wait_dpus_s: float = HEAR_TIMEOUT_S
    logger: str = "local"   # local: lcm-logger here; external: someone else records the run


def control_url(system: System) -> str:
    return system.default_link.url


def default_out(system: System) -> Path:
    return Path("runs") / f"{system.name}-{time.strftime('%Y%m%d-%H%M%S')}"


def run(system: System, options: RunOptions, console: Console | None = None) -> int:
    console = console or Console()
    out = options.out or default_out(system)
    out.mkdir(parents=True, exist_ok=True)
    (out / "system.yaml").write_text(system.source_text)
    url = control_url(system)
    dpu_ids = sorted(d.id for d in system.dpus)
    duration_ns = system.run_duration_ns(options.cycles, options.duration_s)
    for warning in warmup_warnings(system, duration_ns):
        console.print(f"[yellow]WARN[/] {warning}")
    # From the logger's start: first event, clock estimate, START lead, the run, the reports, a margin.
    logger_deadline_s = (LOGGER_READY_S + 1.0 + START_LEAD_S + duration_ns / 1e9 + REPORT_GRACE_S
                         + REPAIR_LIMIT_S + LOGGER_MARGIN_S)
    daemons = []
    if options.spawn:
        dpu_deadline_s = options.wait_dpus_s + 2 * PUSH_TIMEOUT_S + logger_deadline_s
        daemons = [spawn.start_dpu(d.id, url, out / "logs", options.dpu_args, deadline_s=dpu_deadline_s)
                   for d in system.dpus if spawn.is_local(d.host)]
    logger = None
    repair = None
    interrupted = False
    control = Control(url)
    try:
        silent = control.wait_heard(dpu_ids, options.wait_dpus_s,
                                    introduce=lambda g: system.to_config(g, 0, committed=False))
        if silent:
            console.print(f"[red]no heartbeat from DPU {', '.join(map(str, silent))} on {url} in "
                          f"{options.wait_dpus_s:g} s[/]: start them (`skel up FILE` or skel-dpu --id N "
                          "on their hosts), use --spawn, or wait longer (--wait-dpus S)")
            return EXIT_FAILED
        run_id = time.time_ns() // 1_000_000
        generation = options.pushed_generation
        current = {v.status.generation for i, v in control.snapshot().items() if i in dpu_ids}
        if generation is None or current != {generation}:
            generation = control.next_generation()
            pushed = control.push(system.to_config(generation, run_id, committed=False), dpu_ids,
                                  timeout_s=PUSH_TIMEOUT_S)
            if not pushed.ok:
                _print_push_failure(console, pushed)
                return EXIT_FAILED
        if options.logger == "local":
            logger = spawn.start_logger(url, out / "run.lcm", deadline_s=logger_deadline_s)
            # Its file exists before it has joined the group: wait for the first heartbeat it records.
            _wait_nonempty(out / "run.lcm", LOGGER_READY_S)
            repair = LogRepair(control, out / "run.lcm", run_id, dpu_ids)
        clocks = ClockKeeper(control, dpu_ids)
        clocks.refresh()  # before START, so the log has offsets for the whole run
        follower = RunFollower(system, control, console)
        committed = system.to_config(generation, run_id, committed=True)
        try:
            _follow(control, follower, clocks, committed, duration_ns, dpu_ids, repair)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM: end the run, keep what ran, and say so
            interrupted = True
            console.print("interrupted: stopping the run; its report covers what ran")
            control.stop()
        control.wait_for(lambda: all((d, run_id) in control.reports for d in dpu_ids
                                     if d not in follower.lost), REPORT_GRACE_S)
        reports = {d: r for (d, r_id), r in control.reports.items() if r_id == run_id}
        if repair is not None:
            repair.finish(reports, REPAIR_STUCK_S, REPAIR_LIMIT_S)
    finally:
        control.close()
        if logger is not None:
            spawn.stop(logger)
        for daemon in daemons:
            spawn.stop(daemon)
    if logger is None:
        code = _external_summary(console, out, run_id, dpu_ids, reports, follower.lost, options.as_json)
    else:
        code = _report(console, system, options, out, run_id, follower.lost,
                       repair.result if repair is not None else RepairResult())
    return EXIT_INTERRUPTED if interrupted else code


class RunFollower:
    """Watches heartbeats during a run: faults as they happen, when to stop early."""

    def __init__(self, system: System, control: Control, console: Console) -> None:
        self.system = system
        self.control = control
        self.console = console
        self.writer = {b.id: system.process(b.writer) for b in system.buffers}
        self.names = {p.id: p.name for p in system.processes}
        self.lockouts: dict[int, skelmsg.lockout_t] = {}
        self.lost: set[int] = set()      # lost during this run (a restarted DPU stays in it)
        self.back: set[int] = set()
        self.stop_reason: str | None = None

    def poll(self, run_id: int, dpu_ids: list[int]) -> None:
        for view in self.control.snapshot().values():
            if view.status.run_id != run_id:
                continue
            for lockout in view.status.lockouts:
                if lockout.process not in self.lockouts:
                    self.lockouts[lockout.process] = lockout
                    self._announce_lockout(view.status.dpu, lockout)
        views = self.control.snapshot()
        silent = self.control.lost(dpu_ids)
        for dpu_id in silent:
            if dpu_id not in self.lost:
                self.lost.add(dpu_id)
                view = views.get(dpu_id)
                since = f" for {time.monotonic() - view.heard_mono:.2f} s" if view else ""
                self.console.print(f"[bold red]FAULT[/] dpu_lost: DPU {dpu_id} not heard{since}; "
                                   "the run goes on without it")
                if "dpu_lost" in self.system.run.stop_on:
                    self.stop_reason = self.stop_reason or f"DPU {dpu_id} lost"
        for dpu_id in sorted(self.lost - set(silent) - self.back):
            # Restarted: it takes the re-sent config and joins the next run, not this one.
            self.back.add(dpu_id)
            self.console.print(f"DPU {dpu_id} heard again ({views[dpu_id].state}): it joins the next run")

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


def _adopt_pushed(control: Control, config: skelmsg.config_t, dpu_ids: list[int],
                  console: Console) -> skelmsg.config_t:
    """The config to re-send from now on: ours, or the one a `skel push` committed mid-run.

    The DPUs' heartbeats say which generation they apply; the pushed config itself was
    heard on SKEL_CONFIG when `skel push` staged it (from any host), so the follower
    needs no shared file and works when the push comes from another machine."""
    views = control.snapshot()
    applied = [views[i].status.generation for i in dpu_ids if i in views]
    newest = max(applied, default=config.generation)
    if newest <= config.generation:
        return config
    pushed = control.config_of(newest)
    if pushed is None:
        return config  # not heard (yet): keep the old one, a DPU that has the new one ignores it
    adopted = skelmsg.config_t.decode(pushed.encode())  # a copy: the Control's stays as heard
    adopted.committed, adopted.run_id = 1, config.run_id
    console.print(f"generation {newest} committed mid-run: re-sending it from now on")
    return adopted


def _follow(control: Control, follower: RunFollower, clocks: ClockKeeper, config: skelmsg.config_t,
            duration_ns: int, dpu_ids: list[int], repair: LogRepair | None) -> None:
    """Start the run and follow it; re-send the committed config every second meanwhile, so
    a late or restarted DPU catches up and the log holds the configuration of the run.
    A generation committed mid-run by `skel push` replaces ours in the re-sends."""
    run_id = config.run_id
    control.publish_config(config)
    start_utc = time.time_ns() + int(START_LEAD_S * 1e9)
    control.start(config.generation, run_id, start_utc, duration_ns)
    resent = time.monotonic()
    end_utc = start_utc + duration_ns
    columns = [TextColumn("{task.description}"), BarColumn(), TextColumn("{task.percentage:>3.0f}%"),
               TimeRemainingColumn()]
    with Progress(*columns, console=follower.console, transient=True) as progress:
        task = progress.add_task(f"run {run_id}", total=duration_ns / 1e9)
        while time.time_ns() < end_utc + 200_000_000:
            follower.poll(run_id, dpu_ids)
            if follower.stop_reason:
                follower.console.print(f"stopping early: {follower.stop_reason} (run.stop_on)")
                control.stop()
                break
            progress.update(task, completed=max(0.0, (time.time_ns() - start_utc) / 1e9))
            if time.monotonic() - resent >= CONFIG_RESEND_S:
                config = _adopt_pushed(control, config, dpu_ids, follower.console)
                control.publish_config(config)
                resent = time.monotonic()
            if clocks.due():
                clocks.refresh(skip=follower.lost)
            if repair is not None:
                repair.poll()
            time.sleep(POLL_S)
    follower.poll(run_id, dpu_ids)


def _wait_nonempty(path: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while path.stat().st_size == 0 and time.monotonic() < deadline:
        time.sleep(0.02)


def _report(console: Console, system: System, options: RunOptions, out: Path, run_id: int,
            lost: set[int], repaired: RepairResult) -> int:
    try:
        report = analyze(out / "run.lcm", run_id=run_id)
    except LogError as error:
        console.print(f"[red]{out / 'run.lcm'}: {error}[/]")
        return EXIT_FAILED
    (out / "report.json").write_text(json.dumps(report.to_json(), indent=2) + "\n")
    if options.as_json:
        print(json.dumps(report.to_json(), indent=2))
    else:
        paper = None
        if options.compare_paper and system.reference is not None:
            paper = {i: row.model_dump() for i, row in system.reference.dpus.items()}
        print_report(report, console=console, paper=paper)
        if repaired.asked:
            console.print(f"the logger missed {repaired.asked} messages; the DPUs sent them again"
                          + (f", {repaired.missing} still missing" if repaired.missing else ": all logged"))
        console.print(f"run written to {out}/ (system.yaml, run.lcm, report.json)")
    kinds = {f["kind"] for f in report.to_json()["faults"]}
    if kinds & set(FATAL_KINDS):
        return EXIT_FATAL_FLAW
    # A lost DPU's part of the run is missing: the tables cover the others only.
    return EXIT_FAILED if lost or "dpu_lost" in kinds else EXIT_OK


def _external_summary(console: Console, out: Path, run_id: int, dpu_ids: list[int],
                      reports: dict[int, skelmsg.report_t], lost: set[int], as_json: bool) -> int:
    """Without a local log, the DPUs' own end-of-run totals (report_t) are all we have."""
    rows = []
    for dpu in dpu_ids:
        rep = reports.get(dpu)
        if rep is None:
            rows.append({"dpu": dpu, "reported": False})
            continue
        compute, communicate, wait, _ = utilization_pct(rep.compute_ns, rep.communicate_ns,
                                                        rep.wait_ns, rep.elapsed_ns)
        rows.append({"dpu": dpu, "reported": True, "generation": rep.generation,
                     "minor_cycles": rep.minor_cycles, "elapsed_s": rep.elapsed_ns / 1e9,
                     "compute_pct": compute, "communicate_pct": communicate, "wait_pct": wait,
                     "overruns": sum(p.overruns for p in rep.processes),
                     "locked_out": sorted(p.process for p in rep.processes if p.locked_out),
                     "faults": rep.faults})
    summary = {"run_id": run_id, "dpus": rows}
    (out / "reports.json").write_text(json.dumps(summary, indent=2) + "\n")
    if as_json:
        print(json.dumps(summary, indent=2))
    else:
        table = Table(title=f"run {run_id}: the DPUs' own totals (report_t)")
        for column in ("DPU", "minor cycles", "compute %", "comm %", "wait %", "overruns", "locked out"):
            table.add_column(column, justify="right")
        for row in rows:
            if not row["reported"]:
                table.add_row(str(row["dpu"]), "[red]no report[/]", "", "", "", "", "")
                continue
            table.add_row(str(row["dpu"]), str(row["minor_cycles"]), _pct(row["compute_pct"]),
                          _pct(row["communicate_pct"]), _pct(row["wait_pct"]), str(row["overruns"]),
                          ", ".join(map(str, row["locked_out"])) or "-")
        console.print(table)
        console.print(f"the run was recorded by the external logger: `skel report LOG --run-id {run_id}` "
                      "on its log gives the full tables")
    fatal = skelmsg.status_t.FAULT_LOCKOUT | skelmsg.status_t.FAULT_JAM
    if any(r.get("faults", 0) & fatal or r.get("locked_out") for r in rows):
        return EXIT_FATAL_FLAW
    return EXIT_FAILED if lost or not all(r["reported"] for r in rows) else EXIT_OK


def _pct(value: float | None) -> str:
    return "-" if value is None else f"{value:.1f}"


def _print_push_failure(console: Console, pushed: PushResult) -> None:
    for dpu_id, reason in sorted(pushed.rejected.items()):
        console.print(f"[red]DPU {dpu_id} rejected generation {pushed.generation}[/]: {reason}")
    for dpu_id in pushed.silent:
        console.print(f"[red]DPU {dpu_id} did not answer generation {pushed.generation}[/]")
    console.print("nothing was committed: every DPU keeps its previous configuration")
