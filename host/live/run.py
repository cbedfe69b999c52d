"""One run: push the system, start every DPU at one instant, follow, record, report.

The printed tables come from the recorded log through the same analysis as
`skel report`, so what `skel run` shows is exactly what the log alone gives.

What outlives the host tool: the DPUs have the run's duration, so they finish
their cycles if `skel run` dies. The logger is started (once the push has
succeeded) in its own session under `timeout`: a killed host tool neither takes
it down nor leaves it running for ever; it stops by itself about
SETTLE_S + REPORT_GRACE_S + REPAIR_LIMIT_S + LOGGER_MARGIN_S (~21 s) after the run's planned end. On a
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
import os
import sys
import time
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, Progress, TextColumn, TimeRemainingColumn
from rich.table import Table

import skelmsg
from skeleton.analysis.errors import EXIT_FAILED, EXIT_FATAL_FLAW, EXIT_INTERRUPTED, EXIT_OK
from skeleton.analysis.measure.faults import LOST_AFTER_S, Fault
from skeleton.analysis.measure.metrics import utilization_pct
from skeleton.analysis.views.console import OutputConsole
from skeleton.analysis.views.summary import FAILED_KINDS, fault_line
from skelmsg.contract import KEY_ENV

from ..model import System
from . import owner, spawn
from .clock import ClockKeeper
from .control import Control, PushResult
from .listener import DpuView
from .outcome import START_LEAD_S, RunOptions, control_url, fault_window_s, report_run
from .preflight import delivery_warnings, warmup_warnings
from .repair import LoggerKeeper, LogRepair, RepairResult
from .simulate import beside_run
from .wire import config_message

REPORT_GRACE_S = 5.0        # how long after the end we wait for the DPUs' reports
SETTLE_S = 1.0              # ... before a DPU still running the run is sent STOP
CONFIG_RESEND_S = 1.0
POLL_S = 0.1                # follower period: a lost DPU is reported within LOST_AFTER_S + this
PUSH_TIMEOUT_S = 3.0        # per phase (stage, commit) of Control.push
LOGGER_MARGIN_S = 5.0       # an orphaned logger ends this long after the report grace
LOGGER_READY_S = 2.0        # heartbeats come at 5 Hz: the logger has one well within this
REPAIR_STUCK_S = 3.0        # after the reports, the repair of the log gives up this long without progress
REPAIR_LIMIT_S = 10.0       # ... or after this long in all
# The faults said while a run goes on: those run.stop_on may name, and a buffer never delivered.
LIVE_KINDS = ("lockout", "jam", "behind", "stall", "dpu_lost", "delivery")
# The platform's faults (stall, behind) said live before they are only counted: a noisy
# machine makes dozens, and the summary counts them all.
LIVE_PLATFORM_LINES = 3


def default_out(system: System) -> Path:
    return Path("runs") / f"{system.name}-{time.strftime('%Y%m%d-%H%M%S')}"


def run(system: System, options: RunOptions, console: Console | None = None) -> int:
    console = console or OutputConsole()
    out = options.out or default_out(system)
    out.mkdir(parents=True, exist_ok=True)
    (out / "system.yaml").write_text(system.source_text)
    url = control_url(system)
    dpu_ids = sorted(d.id for d in system.dpus)
    duration_ns = system.run_duration_ns(options.cycles, options.duration_s)
    for warning in warmup_warnings(system, duration_ns) + delivery_warnings(system):
        console.print(f"[yellow]WARN[/] {warning}", soft_wrap=True)
    # From the logger's start: first event, clock estimate, START lead, the run, the reports, a margin.
    logger_deadline_s = (LOGGER_READY_S + 1.0 + START_LEAD_S + duration_ns / 1e9 + SETTLE_S + REPORT_GRACE_S
                         + REPAIR_LIMIT_S + LOGGER_MARGIN_S)
    interrupted = False
    control = Control(url, options.key)
    daemons: list[spawn.Daemon] = []
    keeper = None
    repair = None
    problems: list[str] = []
    try:
        if options.spawn:
            # Before anything starts: DPUs of ours already up and busy are someone's run.
            control.wait_for(lambda: set(dpu_ids) <= control.dpus.keys(), owner.HEAR_BEFORE_SPAWN_S)
            # Idle DPUs of our ids (busy ones are someone's run, which claim names, unless we
            # --force it: then spawning beside them would still be wrong).
            up = _already_up(control, system)
            if up is not None and (options.force or not owner.foreign_runs(control, dpu_ids)):
                console.print(f"[red]{up}[/]", soft_wrap=True)
                return EXIT_FAILED
            if not claim(control, dpu_ids, options.force, console):
                return EXIT_FAILED
            dpu_deadline_s = options.wait_dpus_s + 2 * PUSH_TIMEOUT_S + logger_deadline_s
            daemons = [spawn.start_dpu(d.id, url, out / "logs", options.dpu_args, deadline_s=dpu_deadline_s,
                                       key_file=options.key_file)
                       for d in system.dpus if spawn.is_local(d.host)]
        silent = control.wait_heard(dpu_ids, options.wait_dpus_s,
                                    introduce=lambda g: config_message(system, g, 0, committed=False))
        if silent:
            refused = control.key_lines()
            if refused:  # heard, and refused by the key check: starting them or a firewall is not it
                console.print(f"[red]DPU {', '.join(map(str, silent))} not accepted on {url}: the key "
                              f"check refused what was heard[/] (`--key` / ${KEY_ENV} must be the DPUs' "
                              "key, or none on both sides)", soft_wrap=True)
            else:
                console.print(f"[red]no heartbeat from DPU {', '.join(map(str, silent))} on {url} (heard on "
                              f"its record URL {control.record_url}) in {options.wait_dpus_s:g} s[/]: start "
                              "them (`skel up FILE` or skel-dpu --id N on their hosts), use --spawn, or wait "
                              "longer (--wait-dpus S); a firewall must pass both ports")
            for line in refused:
                console.print(f"[red]{line}[/]", soft_wrap=True)
            return EXIT_FAILED
        if not claim(control, dpu_ids, options.force, console):
            return EXIT_FAILED
        run_id = time.time_ns() // 1_000_000
        generation = options.pushed_generation
        current = {v.status.generation for i, v in control.snapshot().items() if i in dpu_ids}
        if generation is None or current != {generation}:
            generation = control.next_generation()
            pushed = control.push(config_message(system, generation, run_id, committed=False), dpu_ids,
                                  timeout_s=PUSH_TIMEOUT_S)
            if not pushed.ok:
                _print_push_failure(console, pushed)
                return EXIT_FAILED
        _print_network(console, control, dpu_ids)
        if options.logger == "local":
            keeper = LoggerKeeper(control.listen_url, out / "run.lcm", logger_deadline_s, say=console.print)
            # Its file exists before it has joined the group: wait for the first heartbeat it records.
            wait_nonempty(out / "run.lcm", LOGGER_READY_S)
            repair = LogRepair(control, out / "run.lcm", run_id, dpu_ids, keeper)
        clocks = ClockKeeper(control, dpu_ids)
        clocks.refresh()  # before START, so the log has offsets for the whole run
        keep_off_dpu_cpus(system, spawn.own_threads())
        follower = RunFollower(system, control, console)
        control.follow(run_id)
        committed = config_message(system, generation, run_id, committed=True)
        try:
            _follow(control, follower, clocks, committed, duration_ns, dpu_ids, repair, out)
        except KeyboardInterrupt:  # Ctrl-C or SIGTERM: end the run, keep what ran, and say so
            interrupted = True
            console.print("interrupted: stopping the run; its report covers what ran")
            control.stop()
        finish(control, run_id, [d for d in dpu_ids if d not in follower.lost], console)
        follower.poll(dpu_ids, running=False)  # what the last heartbeats and batches said
        reports = {d: r for (d, r_id), r in control.reports.items() if r_id == run_id}
        if repair is not None:
            repair.finish(reports, REPAIR_STUCK_S, REPAIR_LIMIT_S)
        if follower.taken_over:
            problems.append(follower.taken_over)
    finally:
        control.close()
        if keeper is not None:
            keeper.stop()
        for daemon in daemons:
            spawn.stop(daemon)
            if (bad := spawn.bad_exit(daemon)) is not None:  # its data so far is kept; it is said
                print(f"warning: {daemon.name} {bad}: see {daemon.log_path}", file=sys.stderr)
    if keeper is None:
        code = _external_summary(console, out, run_id, dpu_ids, reports, follower.lost, options.as_json)
        return EXIT_INTERRUPTED if interrupted else code
    repaired = repair.result if repair is not None else RepairResult()
    if keeper.failure:
        problems.append(keeper.failure)
    if repaired.missing:
        problems.append(f"the log is incomplete: {repaired.missing} of what the DPUs published never "
                        f"reached it (the logger missed {repaired.asked}; asked again, "
                        f"{repaired.missing} could not be had again)")
    simulated, why_not = beside_run(system, out, duration_ns)
    if why_not:
        console.print(why_not, style="yellow", markup=False, highlight=False)
    code = report_run(console, system, options, out, run_id, follower.lost, repaired, keeper.restarts,
                      problems, simulated=simulated)
    return EXIT_INTERRUPTED if interrupted else code


def keep_off_dpu_cpus(system: System, threads: list[int] | None = None) -> set[int]:
    """spawn.keep_off the CPUs this host's DPUs are pinned to, for `threads` (None: the calling
    thread) and those they start from now on; the DPUs and the logger are processes of their
    own, pinned or not by the system file. Returns where the threads run."""
    pinned = {d.cpu for d in system.dpus if d.cpu is not None and spawn.is_local(d.host)}
    return spawn.keep_off(pinned, os.sched_getaffinity(0), threads)


def _already_up(control: Control, system: System) -> str | None:
    """Why --spawn must not start this system's local DPUs: one of their ids already answers
    (`skel up`, say), or will (a daemon started with --id auto on this host). A second daemon
    of an id would run the run beside the first, every buffer arriving twice, and the report
    would take the two for one DPU restarted."""
    local = [d for d in system.dpus if spawn.is_local(d.host)]
    heard = control.snapshot()
    who = [f"DPU {d.id} (pid {heard[d.id].status.pid} on {heard[d.id].status.host})" for d in local
           if d.id in heard]
    # A daemon started with --id auto names no DPU until a config does: it then takes the one
    # DPU of the system whose host is its host name, beside the one --spawn started.
    for view in control.daemons():
        mine = [d.id for d in system.dpus if d.host == view.status.host]
        if view.status.dpu == -1 and len(mine) == 1 and any(d.id == mine[0] for d in local):
            who.append(f"DPU {mine[0]} (pid {view.status.pid} on {view.status.host}, started with --id auto)")
    if not who:
        return None
    return (f"{', '.join(who)} already up on {control.url}: --spawn would start a second DPU of the same "
            "id. Run without --spawn to use them, or stop them first (`skel down`)")


def claim(control: Control, dpu_ids: list[int], force: bool, console: Console) -> bool:
    """Our DPUs are free, or (--force) made free: another session's run is refused or taken over."""
    runs = owner.foreign_runs(control, dpu_ids)
    if not runs:
        return True
    if not force:
        console.print(f"[red]{owner.refusal(runs, 'run')}[/]", soft_wrap=True)
        return False
    for run in runs:
        console.print(f"[yellow]--force: taking over: {run.describe()}; stopping it[/]", soft_wrap=True)
    busy = owner.take_over(control, runs, dpu_ids)
    if busy:
        console.print(f"[red]DPU {', '.join(map(str, busy))} still busy {owner.STOP_WAIT_S:g} s after the "
                      "STOP: not started[/]")
    return not busy


class RunFollower:
    """Follows a run through what the Control hears (listener.py): each fault as it
    appears, as the report will name it, and when to stop early (run.stop_on).

    A DPU is lost when its heartbeats stop (listener.LOST_AFTER_S), and only then: one
    whose processes wait for data that does not come still heartbeats, and is not lost."""

    def __init__(self, system: System, control: Control, console: Console) -> None:
        self.system = system
        self.control = control
        self.console = console
        self.lost: set[int] = set()      # lost during this run (a restarted DPU stays in it)
        self.back: set[int] = set()
        self.stop_reason: str | None = None
        self.taken_over: str | None = None  # another host tool ended our run (--force)
        self.platform_lines = 0          # stalls and platform lateness heard (LIVE_PLATFORM_LINES said)

    def poll(self, dpu_ids: list[int], running: bool = True) -> None:
        # A stall first: the DPUs behind their schedule a search finds with it are its consequence,
        # and the few platform lines said live must name the cause.
        for fault in sorted(self.control.new_faults(running), key=lambda f: f.kind != "stall"):
            if fault.kind not in LIVE_KINDS:
                continue
            if fault.kind in self.system.run.stop_on:
                self.stop_reason = self.stop_reason or _stop_reason(fault)
            if fault.kind == "dpu_lost" and fault.dpu is not None:
                self.lost.add(fault.dpu)
            platform = fault.kind in ("stall", "behind") and not fault.fatal
            if platform:
                self.platform_lines += 1
                if self.platform_lines == LIVE_PLATFORM_LINES + 1:
                    self.console.print("[yellow]STALL[/] more of the platform's stalls: counted at the end",
                                       highlight=False, soft_wrap=True)
                if self.platform_lines > LIVE_PLATFORM_LINES:
                    continue
            style = "bold red" if fault.fatal or fault.kind in FAILED_KINDS else "yellow"
            tail = "; the run goes on without it" if fault.kind == "dpu_lost" and running else ""
            # A stall is the platform's, not the design's: said as such (its detail names the host).
            label, text = ("STALL", fault.detail) if fault.kind == "stall" else ("FAULT", _live_line(fault))
            self.console.print(f"[{style}]{label}[/] {text}{tail}", highlight=False, soft_wrap=True)
        views = self.control.snapshot()
        for dpu_id in sorted(self.lost - set(self.control.lost(dpu_ids)) - self.back):
            # Restarted: it takes the re-sent config and joins the next run, not this one.
            self.back.add(dpu_id)
            state = views[dpu_id].state if dpu_id in views else "?"
            self.console.print(f"DPU {dpu_id} heard again ({state}): it joins the next run")

    def fault_window_s(self) -> float:
        return fault_window_s(self.system)


def _live_line(fault: Fault) -> str:
    """A fault as it is heard, in one short line; the report's tables give the whole detail."""
    if fault.kind == "behind" and not fault.fatal and fault.behind_ms is not None and fault.at_s is not None:
        return (f"behind: DPU {fault.dpu} ran up to {fault.behind_ms:.1f} ms behind its schedule from "
                f"{fault.at_s:.2f} s, kept from running by the platform")
    return fault_line(fault)


def _stop_reason(fault: Fault) -> str:
    if fault.kind in ("lockout", "jam"):
        return f"{fault.kind} of {fault.process}"
    if fault.kind == "stall":
        return f"stall of host {fault.host}"
    if fault.kind == "behind":
        return f"DPU {fault.dpu} behind its schedule"
    return f"DPU {fault.dpu} lost"


def _adopt_pushed(control: Control, config: skelmsg.config_t, dpu_ids: list[int],
                  console: Console, out: Path) -> skelmsg.config_t:
    """The config to re-send from now on: ours, or the one a `skel push` committed mid-run,
    whose system file is written to `out`/system-gN.yaml (the run's system.yaml is the first).

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
    by = f" (pushed by {pushed.sender}{', --force' if pushed.force else ''})" if pushed.sender else ""
    kept = ""
    if adopted.source:
        (out / f"system-g{newest}.yaml").write_text(adopted.source)
        kept = f"; its system file: {out / f'system-g{newest}.yaml'}"
    console.print(f"generation {newest} committed mid-run: re-sending it from now on{by} (to a DPU that "
                  f"rejoins, and into the log){kept}")
    return adopted


def _follow(control: Control, follower: RunFollower, clocks: ClockKeeper, config: skelmsg.config_t,
            duration_ns: int, dpu_ids: list[int], repair: LogRepair | None, out: Path) -> None:
    """Start the run and follow it; re-send the committed config every second meanwhile, so
    a late or restarted DPU catches up and the log holds the configuration of the run.
    A generation committed mid-run by `skel push` replaces ours in the re-sends, and its
    system file goes beside the run's (`out`/system-gN.yaml)."""
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
        stop_at = None
        while time.time_ns() < end_utc + 200_000_000:
            follower.poll(dpu_ids)
            follower.taken_over = owner.taken_over(control, run_id, dpu_ids)
            if follower.taken_over:
                follower.console.print(f"[bold red]{follower.taken_over}[/]", soft_wrap=True)
                break
            if follower.stop_reason and stop_at is None:
                window_s = follower.fault_window_s()
                follower.console.print(f"stopping early: {follower.stop_reason} (run.stop_on), in "
                                       f"{window_s * 1000:.0f} ms (one lockout window)")
                stop_at = time.monotonic() + window_s
            if stop_at is not None and time.monotonic() >= stop_at:
                control.stop()
                break
            progress.update(task, completed=max(0.0, (time.time_ns() - start_utc) / 1e9))
            if time.monotonic() - resent >= CONFIG_RESEND_S:
                config = _adopt_pushed(control, config, dpu_ids, follower.console, out)
                control.publish_config(config)
                resent = time.monotonic()
            if clocks.due():
                clocks.refresh(skip=follower.lost)
            if repair is not None:
                repair.poll()
            time.sleep(POLL_S)
    follower.poll(dpu_ids)
    # A generation committed in the run's last second came after the last re-send: its system
    # file still goes beside the run's, and its config into the log.
    if not follower.taken_over:
        adopted = _adopt_pushed(control, config, dpu_ids, follower.console, out)
        if adopted is not config:
            control.publish_config(adopted)


def finish(control: Control, run_id: int, dpu_ids: list[int], console: Console) -> None:
    """Wait until every DPU has reported the run and is idle (READY) again. One still
    running it SETTLE_S after its end (a DPU behind its releases, or a long computation)
    is sent STOP: when `skel run` returns, the DPUs are ready for the next run."""
    in_run = (skelmsg.status_t.STATE_ARMED, skelmsg.status_t.STATE_RUNNING)

    def running(views: dict[int, DpuView]) -> list[int]:
        # A DPU whose heartbeats stopped is lost (reported as such), not running.
        now = time.monotonic()
        return [d for d in dpu_ids if d in views and views[d].status.run_id == run_id
                and views[d].status.state in in_run and now - views[d].heard_mono <= LOST_AFTER_S]

    def done() -> bool:  # evaluated under the Control's lock: its own dicts, no snapshot
        return all((d, run_id) in control.reports for d in dpu_ids) and not running(control.dpus)

    if control.wait_for(done, SETTLE_S):
        return
    for dpu_id in running(control.snapshot()):
        control.command(skelmsg.command_t.STOP, dpu=dpu_id)
        console.print(f"[yellow]DPU {dpu_id} was still running the run {SETTLE_S:g} s after its end: "
                      "stopped it[/]")
    control.wait_for(done, REPORT_GRACE_S)
    for dpu_id in running(control.snapshot()):
        console.print(f"[red]DPU {dpu_id} is still running run {run_id} after STOP[/]: "
                      "`skel status` shows when it is ready again")


def wait_nonempty(path: Path, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while path.stat().st_size == 0 and time.monotonic() < deadline:
        time.sleep(0.02)


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


def _print_network(console: Console, control: Control, dpu_ids: list[int]) -> None:
    """Each reading DPU's links: which property its host's kernel enforces (tc, nft), which it
    emulates, and why (status_t.network, in the run's log too)."""
    for dpu_id, view in sorted(control.snapshot().items()):
        if dpu_id in dpu_ids and view.status.network:
            console.print(f"NET DPU {dpu_id}: {view.status.network}", highlight=False, markup=False,
                          soft_wrap=True)


def _print_push_failure(console: Console, pushed: PushResult) -> None:
    for fine, text in pushed.outcome():
        console.print(text if fine else f"[red]{text}[/]", highlight=False)
