"""`skel`: the operator's command line (check, up, down, push, run, status, clock, report...).

Exit codes: analysis/errors.py (EXIT_*); every error of skeleton's own is a SkelError that
carries its code, and main() prints it as one line.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import time
from collections.abc import Sequence
from pathlib import Path

from rich.table import Table

from skeleton.analysis.errors import (
    EXIT_BAD_INPUT,
    EXIT_BROKEN_PIPE,
    EXIT_FAILED,
    EXIT_INTERRUPTED,
    SkelError,
)
from skeleton.analysis.read.messages import run_log_path
from skeleton.analysis.read.parallel import one_heap
from skeleton.analysis.read.seal import key_path, load_key, write_key
from skeleton.analysis.views.console import reader_gone, stdout_to_devnull
from skelmsg.contract import DEFAULT_URL, KEY_ENV

from ..live import spawn
from ..live.control import Control
from ..live.listener import QUIET_S, is_run_id
from ..live.wire import config_message
from ..sysfile.system import SystemFileError, load, with_url
from ..theory.predict import deadlocks

UNKEYED = ("check", "keygen", "calibrate")  # commands that neither talk to DPUs nor judge a run's seal
LISTEN_LIMIT_S = 5.0  # `skel status`/`skel clock` listen at most this long by default

# Set once the command has returned: a signal that arrives while the interpreter shuts
# down must not raise into its clean-up (that printed a dump and exited 1).
_exiting = False


def _system_args(parser: argparse.ArgumentParser, optional: bool = False) -> None:
    if optional:
        parser.add_argument("file", type=Path, nargs="?",
                            help="the system file (YAML); default: the one `skel push` applied last")
    else:
        parser.add_argument("file", type=Path, help="the system file (YAML)")
    parser.add_argument("-s", "--set", dest="overrides", action="append", default=[], metavar="KEY=VALUE",
                        help="change one descriptor, e.g. process.executor.compute_us=3000 (repeatable)")
    parser.add_argument("--url", help="LCM URL of the system's default link (overrides the file)")


def _run_args(parser: argparse.ArgumentParser, default_out: str) -> None:
    """What `skel run` and `skel simulate` share: the run's length, its directory, what it prints."""
    length = parser.add_mutually_exclusive_group()
    length.add_argument("--cycles", type=int, help="run length in cycles of the shortest period")
    length.add_argument("--duration", type=float, metavar="S", help="run length in seconds")
    parser.add_argument("--out", type=Path, help=f"run directory (default {default_out})")
    parser.add_argument("--json", action="store_true", help="print report.json instead of one screen")
    parser.add_argument("--all", action="store_true", dest="all_tables",
                        help="print every table, not one screen (the verdict, per DPU, faults and deltas "
                             "counted)")
    parser.add_argument("--compare-paper", action="store_true",
                        help="print the system file's reference values (the paper's Table 1) beside ours")


def _lib_dir_arg(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lib-dir", type=Path, action="append", default=[], metavar="DIR",
                        help="the started DPUs load real code (compute: {library: NAME}) from DIR only "
                             "(repeatable)")


def _lib_dirs(args: argparse.Namespace) -> list[str]:
    """skel-dpu's --lib-dir arguments, each directory absolute."""
    return [a for d in args.lib_dir for a in ("--lib-dir", str(d.resolve()))]


CONTROL_URL_HELP = f"the control URL the DPUs listen on (default {DEFAULT_URL})"


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="skel", description="Run the skeleton of a distributed "
                                     "real-time control system and measure it (NIST skeleton approach).")
    sub = parser.add_subparsers(dest="command", required=True)

    p = sub.add_parser("check", help="validate a system file and print its static load")
    _system_args(p)
    p.add_argument("--json", action="store_true", help="the static view and the prediction as JSON")

    p = sub.add_parser("up", help="start the local skel-dpu daemons of a system and leave them running")
    _system_args(p)
    _lib_dir_arg(p)

    p = sub.add_parser("down", help="stop the daemons `skel up` started")
    p.add_argument("--url", help="only those on this LCM URL")

    p = sub.add_parser("push", help="broadcast a (changed) system to running DPUs, without restarting them")
    _system_args(p)
    p.add_argument("--at-ms", type=float, default=300.0, metavar="N",
                   help="commit N ms from now: DPUs in a run all switch at their first release at or "
                        "after that instant (default 300)")
    p.add_argument("--force", action="store_true",
                   help="push even into a run another host tool started (the DPUs log who did it)")

    p = sub.add_parser("run", help="push, run at one shared instant, record, and print one screen of it")
    _system_args(p, optional=True)
    p.add_argument("--spawn", action="store_true", help="start local DPUs for this run and stop them after")
    _lib_dir_arg(p)
    _run_args(p, "runs/<system>-<time>/")
    p.add_argument("--wait-dpus", type=float, default=5.0, metavar="S",
                   help="wait up to S seconds for every DPU's first heartbeat (default 5)")
    p.add_argument("--logger", choices=("local", "external"), default="local",
                   help="local: record run.lcm with lcm-logger here (default); external: a logger "
                        "runs elsewhere, print the DPUs' own totals and analyse that log with `skel report`")
    p.add_argument("--force", action="store_true",
                   help="take over the DPUs when another host tool's run holds them: stop it, then run")
    p.add_argument("--no-check", action="store_true",
                   help="run even a system `skel check` refuses (a data-wait deadlock: it locks out)")

    p = sub.add_parser("simulate", help="run the whole system on virtual time here, in seconds: the same "
                       "log, report and one screen as `skel run`, the same every time")
    _system_args(p)
    _run_args(p, "runs/<system>-sim-<time>/")
    p.add_argument("--push", action="append", default=[], metavar="S:FILE",
                   help="push FILE S seconds into the run, as `skel push` would: every DPU switches "
                        "at the first boundary they share from then (repeatable)")
    p.add_argument("--no-check", action="store_true",
                   help="simulate even a system `skel check` refuses (a data-wait deadlock: it locks out)")

    listen = (f"listen until no new DPU was heard for {QUIET_S:g} s, at most S seconds "
              f"(default {LISTEN_LIMIT_S:g})")
    p = sub.add_parser("clock", help="estimate each DPU's clock offset and round trip (ping, best of N)")
    p.add_argument("--url", default=DEFAULT_URL, help=CONTROL_URL_HELP)
    p.add_argument("--samples", type=int, default=8, help="pings per DPU (default 8)")
    p.add_argument("--wait", type=float, default=LISTEN_LIMIT_S, metavar="S", help=listen)
    p.add_argument("--json", action="store_true", help="each DPU's offset and round trip as JSON")

    p = sub.add_parser("status", help="the DPUs heard on the control channel")
    p.add_argument("--url", default=DEFAULT_URL, help=CONTROL_URL_HELP)
    p.add_argument("--json", action="store_true", help="every DPU heard, as JSON")
    p.add_argument("--wait", type=float, default=LISTEN_LIMIT_S, metavar="S", help=listen)

    p = sub.add_parser("report", help="the tables of a recorded run, from its log alone")
    p.add_argument("log", type=Path, help="run.lcm, run.mcap, or a run directory")
    p.add_argument("--json", action="store_true", help="print report.json instead of one screen")
    p.add_argument("--run-id", type=int, help="which run, when the log holds several (default the last)")
    p.add_argument("--all", action="store_true", dest="all_tables",
                   help="print every table, not one screen (the verdict, per DPU, faults and deltas counted)")
    p.add_argument("--plots", type=Path, metavar="DIR", help="also write PNG plots and report.html to DIR")

    p = sub.add_parser("diff", help="two runs' tables side by side, with deltas")
    p.add_argument("run_a", type=Path)
    p.add_argument("run_b", type=Path)
    p.add_argument("--json", action="store_true", help="the deltas as JSON")

    p = sub.add_parser("export", help="a run as MCAP (Foxglove), Parquet tables or a Perfetto trace")
    p.add_argument("log", type=Path, help="run.lcm, or a run directory")
    p.add_argument("mcap", type=Path, nargs="?", help="write the run as this MCAP file")
    p.add_argument("--run-id", type=int)
    p.add_argument("--parquet", type=Path, metavar="DIR", help="write its tables as DIR/<table>.parquet")
    p.add_argument("--trace", type=Path, metavar="FILE.json", help="write a Chrome/Perfetto trace of the run")

    p = sub.add_parser("watch", help="live view of a run (or of lcm-logplayer replaying one)")
    p.add_argument("--url", default=DEFAULT_URL, help=CONTROL_URL_HELP)
    p.add_argument("--once", action="store_true", help="print the final table when the run ends, then exit")
    p.add_argument("--all", action="store_true", dest="all_tables",
                   help="with --once: every table, not one screen (as skel report --all)")
    p.add_argument("--duration", type=float, metavar="S", help="stop watching after S seconds")
    p.add_argument("--json", action="store_true", help="with --once: the final report as JSON (report.json)")

    p = sub.add_parser("event", help="send a named event to the processes awaiting it (sync: event)")
    p.add_argument("name", help="the event, as the system file names it (an `events:` entry of kind host)")
    p.add_argument("--count", type=int, default=1, help="how many (default 1)")
    p.add_argument("--rate", type=float, default=10.0, metavar="HZ", help="events per second (default 10)")
    p.add_argument("--url", default=DEFAULT_URL, help=CONTROL_URL_HELP)

    from .margin_cmd import add_parser as add_margin

    _system_args(add_margin(sub))
    from .allocate_cmd import add_parser  # ortools loads only for `skel allocate`
    _system_args(add_parser(sub))
    from .calibrate_cmd import add_parser as add_calibrate

    add_calibrate(sub)

    p = sub.add_parser("console", help="serve the operator's web page: the system drawn, edits predicted, "
                                       "pushed and run, runs compared (prints its URL with a token)")
    p.add_argument("file", type=Path, nargs="?",
                   help="the system file (YAML); default: the one `skel push` applied last")
    p.add_argument("--url", help="LCM URL of the system's default link (overrides the file)")
    p.add_argument("--host", default="127.0.0.1", metavar="ADDR",
                   help="the address to serve on (default 127.0.0.1: this machine only)")
    p.add_argument("--port", type=int, default=8767, metavar="N",
                   help="the TCP port (default 8767; 0: any free one)")
    p.add_argument("--spawn", action="store_true", help="the page's Run starts local DPUs for each run")
    p.add_argument("--runs-dir", type=Path, default=Path("runs"), metavar="DIR",
                   help="where the page's runs are recorded (default runs/)")

    p = sub.add_parser("doctor", help="check what would break LCM multicast here, with the fix for each")
    p.add_argument("--url", default=DEFAULT_URL, help=CONTROL_URL_HELP)
    p.add_argument("--json", action="store_true", help="every check as JSON")

    p = sub.add_parser("keygen", help="write a new random key for signed control (mode 0600)")
    p.add_argument("file", type=Path, help="the key file to create (never overwritten)")

    for name, p in sub.choices.items():
        if name not in UNKEYED:
            p.add_argument("--key", type=Path, metavar="FILE",
                           help=f"sign and check control with this key (default ${KEY_ENV} when set; "
                                "none: unauthenticated)")
    return parser


def _interrupted(_signum: int, _frame: object) -> None:
    # SIGTERM (systemd, timeout, kill, a CI runner) ends us like Ctrl-C: `skel run` stops the
    # run, writes its report and its logger and DPUs stop; every command exits EXIT_INTERRUPTED.
    if not _exiting:
        raise KeyboardInterrupt


def main(argv: Sequence[str] | None = None) -> int:
    global _exiting
    try:
        try:
            args = build_parser().parse_args(argv)
            one_heap()  # the analysis's threads share one heap (a run's report, an export)
            signal.signal(signal.SIGTERM, _interrupted)
            if signal.getsignal(signal.SIGINT) is signal.default_int_handler:  # not when started ignoring it
                signal.signal(signal.SIGINT, _interrupted)
            if args.command not in UNKEYED:
                args.key_file = key_path(args.key)
                args.key = load_key(args.key_file) if args.key_file is not None else None
            code = COMMANDS[args.command](args)
        finally:
            # What is still buffered goes now, where a reader gone is caught below, not in
            # Python's flush at exit ("Exception ignored", exit 120); --help's text too.
            sys.stdout.flush()
        # The reader stopped reading (`skel report | head`, `skel run | grep -m1 FAULT`):
        # the command finished quietly (console.py); it ends as a tool killed by SIGPIPE does.
        return EXIT_BROKEN_PIPE if reader_gone() else code
    except SkelError as error:   # one line, the code it carries: never a traceback
        print(error.line(), file=sys.stderr)
        return error.exit_code
    except KeyboardInterrupt:
        return EXIT_INTERRUPTED
    except BrokenPipeError:  # a plain print (--json) to a reader gone: no traceback
        stdout_to_devnull()
        return EXIT_BROKEN_PIPE
    finally:
        _exiting = True


def _load(args: argparse.Namespace):  # type: ignore[no-untyped-def]
    system = load(args.file, args.overrides)
    return with_url(system, args.url) if args.url else system


def cmd_check(args: argparse.Namespace) -> int:
    from .check import check

    return check(args.file, args.overrides, as_json=args.json)


def cmd_up(args: argparse.Namespace) -> int:
    from ..live.outcome import control_url

    system = _load(args)
    url = control_url(system)
    local = [d.id for d in system.dpus if spawn.is_local(d.host)]
    started = spawn.up(local, url, args.key_file, _lib_dirs(args))
    print(f"DPUs up on {url}: started {started or 'none'}, already running "
          f"{sorted(set(local) - set(started)) or 'none'}")
    return 0


def cmd_down(args: argparse.Namespace) -> int:
    stopped = spawn.down(args.url)
    print(f"stopped DPU {', '.join(map(str, stopped))}" if stopped else "no DPU was up")
    return 0


def cmd_push(args: argparse.Namespace) -> int:
    from ..live import owner
    from ..live.outcome import HEAR_TIMEOUT_S, control_url

    if args.at_ms < 0:
        print(f"skel push: --at-ms {args.at_ms:g}: must be >= 0", file=sys.stderr)
        return EXIT_BAD_INPUT
    system = _load(args)
    control = Control(control_url(system), args.key)
    try:
        ids = sorted(d.id for d in system.dpus)
        control.wait_heard(ids, HEAR_TIMEOUT_S,
                           introduce=lambda g: config_message(system, g, 0, committed=False))
        foreign = owner.foreign_runs(control, ids)
        if foreign and not args.force:
            print(owner.refusal(foreign, "push"), file=sys.stderr)
            return EXIT_FAILED
        control.force = args.force
        for dpu_id, stray in sorted(control.foreign_generations(ids).items()):
            print(f"DPU {dpu_id}: applied generation {stray}, which no host tool makes (a stray "
                  "config?): it takes no newer one until restarted", file=sys.stderr)
        generation = control.next_generation()
        # Pushed during a run, the config names that run, so its log pairs them.
        runs = {v.status.run_id for i, v in control.snapshot().items()
                if i in ids and v.state in ("armed", "running") and is_run_id(v.status.run_id)}
        run_id = runs.pop() if len(runs) == 1 else 0
        config = config_message(system, generation, run_id, committed=False)
        result = control.push(config, ids, at_ms=args.at_ms)
    finally:
        control.close()
    if result.committed:
        when = time.strftime("%H:%M:%S", time.gmtime(result.at_utc_ns / 1e9))
        print(f"generation {generation}: staged on every DPU, committed for {when}."
              f"{result.at_utc_ns // 1_000_000 % 1000:03d} UTC (the DPUs switch to it then: --at-ms "
              f"{args.at_ms:g} after this push committed it)"
              + (f", mid-run in run {run_id} (at the first cycle boundary all DPUs share from then)"
                 if run_id else ""))
    for fine, text in result.outcome():
        print(text, file=sys.stdout if fine else sys.stderr)
    if not result.committed:
        return EXIT_FAILED
    spawn.remember_push(control_url(system), system.source_text, generation)
    return 0 if result.ok else EXIT_FAILED


def cmd_run(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.console import output_console

    from ..live.run import RunOptions, run

    pushed_generation = None
    if args.file is None:
        url = args.url or DEFAULT_URL
        remembered = spawn.last_push(url)
        if remembered is None:
            print(f"skel run: no system file given and nothing pushed on {url} yet", file=sys.stderr)
            return EXIT_BAD_INPUT
        args.file, pushed_generation = remembered
    system = _load(args)
    if not args.no_check and (refused := deadlocks(system)[0]):
        for problem in refused:
            print(SystemFileError(system.path, problem.path, problem.problem), file=sys.stderr)
        print("skel run: refused (--no-check runs it anyway, and it locks out)", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.wait_dpus < 0:
        print(f"skel run: --wait-dpus {args.wait_dpus:g}: must be >= 0", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.lib_dir and not args.spawn:
        print("skel run: --lib-dir is for the DPUs --spawn starts: give it to skel-dpu (or skel up) instead",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    options = RunOptions(spawn=args.spawn, cycles=args.cycles, duration_s=args.duration, out=args.out,
                         as_json=args.json, compare_paper=args.compare_paper, all_tables=args.all_tables,
                         pushed_generation=pushed_generation, wait_dpus_s=args.wait_dpus,
                         dpu_args=_lib_dirs(args),
                         logger=args.logger, force=args.force, key=args.key, key_file=args.key_file)
    return run(system, options, console=output_console())


def cmd_simulate(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.console import output_console

    from ..live.outcome import RunOptions
    from ..live.simulate import Push, simulate

    system = _load(args)
    if coded := next((p for p in system.processes if p.code), None):
        print(f"skel simulate: process {coded.name} runs real code (compute: library "
              f"{coded.code.library}), which virtual time cannot time: run it on DPUs "
              "(skel run --spawn --lib-dir DIR)", file=sys.stderr)
        return EXIT_BAD_INPUT
    pushes = []
    for given in args.push:
        at, _, name = given.partition(":")
        try:
            at_s = float(at)
        except ValueError:
            at_s = -1.0
        if not name or not 0 < at_s < system.run_duration_ns(args.cycles, args.duration) / 1e9:
            print(f"skel simulate: --push {given}: expected S:FILE, S seconds into the run (> 0, before "
                  "its end)", file=sys.stderr)
            return EXIT_BAD_INPUT
        pushes.append(Push(at_s, load(Path(name))))
    if not args.no_check and (refused := deadlocks(system)[0]):
        for problem in refused:
            print(SystemFileError(system.path, problem.path, problem.problem), file=sys.stderr)
        print("skel simulate: refused (--no-check simulates it anyway, and it locks out)", file=sys.stderr)
        return EXIT_BAD_INPUT
    options = RunOptions(cycles=args.cycles, duration_s=args.duration, out=args.out, as_json=args.json,
                         compare_paper=args.compare_paper, all_tables=args.all_tables)
    return simulate(system, options, console=output_console(), pushes=pushes)


def _listen(control: Control, args: argparse.Namespace) -> float:
    """Listen for the DPUs as --wait says; the seconds listened, said on stderr."""
    listened = control.listen(args.wait)
    print(f"listened {listened:.1f} s on {args.url} (until no new DPU for {QUIET_S:g} s, "
          f"at most {args.wait:g} s)", file=sys.stderr)
    return listened


def cmd_status(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.console import output_console

    from ..live import owner

    if args.wait < 0:
        print(f"skel status: --wait {args.wait:g}: must be >= 0", file=sys.stderr)
        return EXIT_BAD_INPUT
    control = Control(args.url, args.key)
    try:
        listened = _listen(control, args)
        views = control.daemons()
    finally:
        control.close()
    _say_key(control, args)
    now = time.monotonic()
    # Every daemon heard: DPUs started with --id auto are DPU -1 until a config names them.
    rows = [{"dpu": v.status.dpu, "host": v.status.host, "pid": v.status.pid, "state": v.state,
             "generation": v.status.generation, "staged": v.status.staged_generation,
             "run_id": v.status.run_id, "minor_cycles": v.status.minor_cycles,
             "faults": v.status.faults, "rejected_messages": v.status.rejected_messages,
             "keyed": bool(v.status.keyed),
             "refused": {k: getattr(v.status, f"rejected_{k}")
                         for k in ("unsigned", "signed", "forged", "replayed")},
             "reject_reason": v.status.reject_reason,
             # A finished run's owner owns nothing: the DPU keeps the name, the row does not show it.
             "run_owner": v.status.run_owner if v.state in owner.BUSY else None,
             "run_end_utc_ns": v.status.run_end_utc_ns if v.state in owner.BUSY else None,
             "heard_s_ago": round(now - v.heard_mono, 2)}
            for v in views]
    done = _json_or_nothing(rows, args.json, f"no DPU heard on {args.url} (its record URL "
                                              f"{control.record_url}) in {listened:.1f} s")
    if done is not None:
        return done
    table = Table(title=f"DPUs on {args.url}")
    columns = ("dpu", "host", "pid", "state", "generation", "run_id", "run_owner", "minor_cycles", "faults",
               "rejected_messages", "reject_reason", "heard_s_ago")
    for column in columns:
        table.add_column(column)
    for row in rows:
        table.add_row(*("auto" if c == "dpu" and row[c] == -1 else "" if row[c] is None else str(row[c])
                        for c in columns))
    output_console().print(table)
    return 0


def _say_key(control: Control, args: argparse.Namespace) -> None:
    """On stderr: that control is unauthenticated (no key), and every DPU whose key disagrees."""
    if args.key is None:
        print(f"control on {args.url} is unauthenticated (no key): anyone on the group can command the "
              f"DPUs; see `skel keygen` and --key / ${KEY_ENV}", file=sys.stderr)
    for line in control.key_lines():
        print(line, file=sys.stderr)


def _json_or_nothing(rows: list[dict], as_json: bool, nothing: str) -> int | None:
    """Print `rows` as JSON, or say that nothing was heard: the exit code; None: print a table."""
    if as_json:
        print(json.dumps(rows, indent=2))
        return 0
    if not rows:
        print(nothing)
        return EXIT_FAILED
    return None


def cmd_clock(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.console import output_console

    from ..live import clock

    if args.samples < 1 or args.wait < 0:
        what = (f"--samples {args.samples}: must be >= 1" if args.samples < 1
                else f"--wait {args.wait:g}: must be >= 0")
        print(f"skel clock: {what}", file=sys.stderr)
        return EXIT_BAD_INPUT
    control = Control(args.url, args.key)
    try:
        listened = _listen(control, args)
        ids = sorted(i for i in control.snapshot() if i >= 0)
        found = clock.estimate(control, ids, samples=args.samples)
        clock.publish(control, found)  # for the logger, on the record URL
    finally:
        control.close()
    for line in control.key_lines():
        print(line, file=sys.stderr)
    rows = [e.to_json() for _, e in sorted(found.items())]
    done = _json_or_nothing(rows, args.json,
                            f"no DPU heard on {args.url} (its record URL {control.record_url}) in "
                            f"{listened:.1f} s (or none answered the pings)")
    if done is not None:
        return done
    table = Table(title=f"clock offsets on {args.url} (DPU - host, best of {args.samples})")
    for column in ("dpu", "offset", "round trip"):
        table.add_column(column, justify="right")
    for row in rows:
        table.add_row(str(row["dpu"]), f"{row['offset_ns'] / 1e3:+.1f} µs", f"{row['rtt_ns'] / 1e3:.1f} µs")
    output_console().print(table)
    missing = sorted(set(ids) - set(found))
    if missing:
        print(f"no answer to the pings from DPU {', '.join(map(str, missing))}")
    return 0


def cmd_report(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.report import report_command

    from ..theory.predictor import predictor

    log = run_log_path(args.log)
    # a run directory's system.yaml is the file its configuration came from
    return report_command(log, as_json=args.json, run_id=args.run_id, plots=args.plots,
                          predictor=predictor(log.parent / "system.yaml"), key=args.key,
                          all_tables=args.all_tables)


def cmd_diff(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.diff import diff_command

    return diff_command(run_log_path(args.run_a), run_log_path(args.run_b), as_json=args.json, key=args.key)


def cmd_export(args: argparse.Namespace) -> int:
    from skeleton.analysis.views.export import export_command

    return export_command(run_log_path(args.log), args.mcap, run_id=args.run_id, parquet=args.parquet,
                          trace=args.trace, key=args.key)


def cmd_watch(args: argparse.Namespace) -> int:
    from .watch import watch_command

    if args.json and not args.once:
        print("skel watch: --json needs --once (a live view has no final report)", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.all_tables and not args.once:
        print("skel watch: --all needs --once (the live view is one table)", file=sys.stderr)
        return EXIT_BAD_INPUT
    return watch_command(args.url, once=args.once, duration_s=args.duration, as_json=args.json, key=args.key,
                         all_tables=args.all_tables)


def cmd_margin(args: argparse.Namespace) -> int:
    from .margin_cmd import margin_command

    return margin_command(args, _load(args))


def cmd_allocate(args: argparse.Namespace) -> int:
    from .allocate_cmd import allocate_command

    return allocate_command(args)


def cmd_calibrate(args: argparse.Namespace) -> int:
    from .calibrate_cmd import calibrate_command

    return calibrate_command(args)


def cmd_console(args: argparse.Namespace) -> int:
    from ..console.serve import console_command  # starlette and uvicorn load only for the console

    return console_command(args)


def cmd_doctor(args: argparse.Namespace) -> int:
    from .doctor import doctor

    return doctor(args.url, as_json=args.json, keyed=args.key is not None)


def cmd_event(args: argparse.Namespace) -> int:
    from ..live import event
    from ..sysfile.schema import name_problem  # an event's name is the system file's: its channel's suffix

    problem = (name_problem(args.name) if name_problem(args.name)
               else "--count must be >= 1" if args.count < 1
               else "--rate must be a positive number" if not 0 < args.rate < float("inf") else "")
    if problem:
        print(f"skel event {args.name}: {problem}", file=sys.stderr)
        return EXIT_BAD_INPUT
    try:
        sent = event.send(args.url, args.name, args.count, args.rate)  # not signed (README: Security)
    except ValueError as error:  # a URL whose record URL is none (host/sysfile/link.py)
        print(f"skel event {args.name}: {error}", file=sys.stderr)
        return EXIT_BAD_INPUT
    print(f"sent {sent} event{'s' if sent != 1 else ''} {args.name} on {args.url}")
    return 0


def cmd_keygen(args: argparse.Namespace) -> int:
    try:
        write_key(args.file)
    except FileExistsError:
        print(f"skel keygen: {args.file} exists: a key is never overwritten (remove it first)",
              file=sys.stderr)
        return EXIT_BAD_INPUT
    except OSError as e:
        print(f"skel keygen: {args.file}: {e.strerror}", file=sys.stderr)
        return EXIT_FAILED
    print(f"wrote a new key to {args.file} (mode 0600): copy it to every DPU host "
          f"(/etc/skel/key for the systemd unit) and give it to skel with --key or ${KEY_ENV}")
    return 0


COMMANDS = {"check": cmd_check, "up": cmd_up, "down": cmd_down, "push": cmd_push, "run": cmd_run,
            "simulate": cmd_simulate,
            "status": cmd_status, "clock": cmd_clock, "report": cmd_report, "diff": cmd_diff,
            "export": cmd_export, "watch": cmd_watch, "doctor": cmd_doctor, "event": cmd_event,
            "allocate": cmd_allocate, "margin": cmd_margin, "keygen": cmd_keygen,
            "console": cmd_console, "calibrate": cmd_calibrate}

