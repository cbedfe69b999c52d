"""The report as rich tables: per DPU (the paper's Table 1), per process, per input,
per buffer (transport latency and loss), per chain, faults; one set per generation
window when the config changed mid-run.

Rendering is deterministic (no clock, no terminal-dependent content beyond the
console's width), so `skel run` and `skel report` print the same tables for one run.
Printed to a file or a pipe, nothing limits the width (see console.output_console).
"""

from __future__ import annotations

from typing import Any

from rich.console import Console
from rich.table import Table

from ..measure.predicted import PLATFORM, Beside, Predicted
from ..measure.report import RunReport
from ..measure.windows import WindowReport
from .console import output_console


def signed(value: float | None, digits: int = 1) -> str:
    """A difference with its sign: +0.0, never -0.0, for one that rounds to nothing."""
    if value is None:
        return "-"
    return f"{round(value, digits) + 0.0:+.{digits}f}"


def num(value: float | None, digits: int = 1) -> str:
    if value is None:
        return "-"
    if abs(value) >= 1000:
        digits = 0  # the decimals of a large figure are noise and cost width
    # + 0.0: a sum that is zero up to rounding (100 - the other three %) shows 0.0, not -0.0
    return f"{round(value, digits) + 0.0:.{digits}f}"


def make_table(title: str, columns: list[tuple[str, bool]], rows: list[list[str]]) -> Table:
    """A table that never cuts a figure or a word: a number column (flag True) is as
    wide as its widest cell, a text column as its longest word (wrapped between words)."""
    table = Table(title=title)
    for i, (name, numeric) in enumerate(columns):
        words = [w for text in [name, *(r[i] for r in rows)] for w in text.split()]
        if numeric:
            widest = max([len(line) for r in rows for line in r[i].split("\n")] + [len(w) for w in words])
            table.add_column(name, justify="right", no_wrap=True, min_width=widest)
        else:
            table.add_column(name, overflow="fold", min_width=min(24, max(len(w) for w in words)))
    for row in rows:
        table.add_row(*row)
    return table


def _paper(paper: dict[Any, Any] | None, dpu: int) -> dict[str, Any] | None:
    if not paper:
        return None
    return paper.get(dpu) or paper.get(str(dpu))


def dpu_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per DPU of the report (or of one of its generation windows): the paper's Table 1."""
    part = window or report
    rows = [
        [
            str(d.id),
            num(d.configured_cycle_ms, 2),
            num(d.measured_cycle_ms, 2),
            ", ".join(d.processes),
            num(d.compute_pct),
            num(d.communicate_pct),
            num(d.wait_pct),
            num(d.overhead_pct),
            num(d.static_load_pct),
            num(d.release_latency_us.p99, 0),
            num(d.stall_ms),
        ]
        for d in part.dpus
    ]
    columns = [
        ("DPU", True), ("cycle\nms", True), ("meas.\nms", True), ("processes", False),
        ("%\ncomp", True), ("%\ncomm", True), ("%\nwait", True), ("%\novhd", True), ("load\n%", True),
        ("wake\np99 µs", True), ("stall\nms", True),
    ]  # fmt: skip
    title = f"{report.system}: run {report.run_id}, generation {part.generation}: per DPU (load = configured)"
    table = make_table(title, columns, rows)
    # A row of dashes says nothing by itself: a short run, or a window opened by a live switch
    # late in the run, may end before a slow DPU's warm-up does.
    unmeasured = [str(d.id) for d in part.dpus if d.records == 0]
    if unmeasured:
        table.caption = (f"DPU {', '.join(unmeasured)}: no measured cycle here (its warm-up, "
                         "warmup_cycles of its longest period, outlasted this window, or it ran none)")
    return table


def paper_table(report: RunReport, paper: dict[Any, Any], window: WindowReport | None = None) -> Table:
    """Ours beside a published table (`reference:` in the system file, e.g. the paper's Table 1)."""
    rows = []
    for d in (window or report).dpus:
        ref = _paper(paper, d.id) or {}

        def theirs(key: str, digits: int = 1, ref: dict[str, Any] = ref) -> str:
            return num(ref.get(key), digits)

        # a DPU with no measured cycle (its warm-up outlasted the run) has no figure to compare
        delta = None if ref.get("compute_pct") is None or d.compute_pct is None \
            else d.compute_pct - ref["compute_pct"]
        rows.append([
            str(d.id), theirs("cycle_ms", 2), num(d.measured_cycle_ms, 2),
            theirs("compute_pct"), num(d.compute_pct), signed(delta),
            theirs("communicate_pct"), num(d.communicate_pct), theirs("wait_pct"), num(d.wait_pct),
        ])  # fmt: skip
    columns = [
        ("DPU", True), ("cycle\npaper", True), ("ms\nours", True), ("comp\npaper", True),
        ("%\nours", True), ("Δ", True), ("comm\npaper", True), ("%\nours", True),
        ("wait\npaper", True), ("%\nours", True),
    ]  # fmt: skip
    return make_table("the paper's Table 1 beside this run", columns, rows)


def process_table(report: RunReport, window: WindowReport | None = None) -> Table:
    rows = []
    for p in (window or report).processes:
        lat = p.latency_us
        rows.append(
            [
                p.name,
                str(p.dpu),
                str(p.cycles),
                str(p.overruns),
                num(lat.p50),
                num(lat.p99),
                num(lat.max),
                num(p.compute_mean_us),
                num(p.lateness_us.p99),
                f"{p.late}/{p.too_late}",
                str(p.releases_skipped),
            ]
        )
    columns = [
        ("process", False), ("DPU", True), ("cycles", True), ("ovr", True), ("p50", True),
        ("p99", True), ("max", True), ("compute\nmean", True), ("lateness\np99", True),
        ("late/\ntoo late", True), ("skipped\nreleases", True),
    ]  # fmt: skip
    title = (
        "per process: release latency (start - release), compute and lateness (start - the "
        f"schedule's start) in µs; the warm-up ({report.warmup_cycles} cycles of each DPU's slowest "
        "process) excluded"
    )
    return make_table(title, columns, rows)


def compute_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per process whose compute varies: the draws it was asked to emulate beside what it took."""
    rows = [
        [p.name, num(p.asked_mean_us), num(p.compute_mean_us), num(p.asked_us.p99), num(p.compute_us.p99),
         num(p.asked_us.max), num(p.compute_us.max)]
        for p in (window or report).processes if p.varying
    ]  # fmt: skip
    columns = [("process", False), ("mean\nasked", True), ("mean\ntook", True), ("p99\nasked", True),
               ("p99\ntook", True), ("max\nasked", True), ("max\ntook", True)]  # fmt: skip
    title = "per process whose compute varies: compute asked (the draws) and taken, in µs"
    return make_table(title, columns, rows)


def event_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per `sync: event` process: its events handled, dropped and queued, and how long they waited."""
    rows = [
        [p.name, e.event, str(e.handled), str(e.dropped), str(e.queued_max), num(e.latency_us.p50),
         num(e.latency_us.p99), num(e.latency_us.max), num(e.response_us.p50), num(e.response_us.p99),
         num(e.response_us.max)]
        for p in (window or report).processes if (e := p.events) is not None
    ]  # fmt: skip
    columns = [("process", False), ("event", False), ("handled", True), ("dropped", True),
               ("queued\nmax", True), ("latency\np50", True), ("latency\np99", True), ("latency\nmax", True),
               ("resp.\np50", True), ("resp.\np99", True), ("resp.\nmax", True)]  # fmt: skip
    title = ("per process awaiting an event: events handled, dropped (queue full) and the most waiting; "
             "latency (event -> start) and response (event -> end) in µs")
    return make_table(title, columns, rows)


def input_table(report: RunReport, window: WindowReport | None = None) -> Table:
    rows = [
        [p.name, i.buffer, str(i.new), str(i.stale), str(i.dropped), str(i.received)]
        for p in (window or report).processes
        for i in p.inputs
    ]
    columns = [("process", False), ("input buffer", False), ("new", True), ("stale", True),
               ("dropped", True), ("received", True)]  # fmt: skip
    return make_table("per input buffer: cycles with new / stale data, sequences dropped", columns, rows)


def response_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per process: response time (end of work - release) and slack (next release - end)."""
    rows = [
        [p.name, num(p.response_us.p50), num(p.response_us.p99), num(p.response_us.max),
         num(p.slack_us.min), num(p.slack_us.mean)]
        for p in (window or report).processes
    ]  # fmt: skip
    columns = [("process", False), ("resp.\np50", True), ("resp.\np99", True), ("resp.\nmax", True),
               ("slack\nmin", True), ("slack\nmean", True)]  # fmt: skip
    return make_table("per process: response (end - release) and slack (next release - end) in µs", columns,
                      rows)


def buffer_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per buffer and reader: transport latency (send -> receive) and loss."""
    rows = []
    for b in (window or report).buffers:
        for r in b.readers:
            lat = r.latency_us
            rows.append([b.buffer, f"{b.writer} -> {r.process}", num(lat.p50), num(lat.p99), num(lat.max),
                         str(r.unpublished), str(r.superseded), str(r.lost)])  # fmt: skip
    columns = [("buffer", False), ("writer -> reader", False), ("p50", True), ("p99", True), ("max", True),
               ("unpub-\nlished", True), ("super-\nseded", True), ("lost", True)]  # fmt: skip
    title = (
        "per buffer: transport latency in µs (send -> receive, clock offsets removed); "
        "of the dropped sequences, unpublished ones their writer skipped, superseded ones were received, "
        "lost ones never"
    )
    return make_table(title, columns, rows)


def link_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per link: offered load against its bandwidth, loss and transport beside the model."""
    rows = []
    for k in (window or report).links:
        use = num(k.utilization_pct) + (" saturated" if k.saturated else "") if k.bandwidth_mbps else "-"
        rows.append([k.link, str(k.buffers), num(k.messages_per_s, 0), num(k.offered_mbps, 3),
                     num(k.bandwidth_mbps, 3) if k.bandwidth_mbps else "-", use,
                     f"{k.lost} ({num(k.lost_pct, 2)} %)", num(k.modelled_loss_pct, 2),
                     num(k.modelled_delay_us), num(k.transport_p99_us), num(k.transport_max_us),
                     num(k.modelled_queue_us) if k.bandwidth_mbps else "-", num(k.queue_p99_us)])  # fmt: skip
    columns = [("link", False), ("buf-\nfers", True), ("msgs/s", True), ("offered\nMbit/s", True),
               ("band-\nwidth", True), ("% used", True), ("lost", True), ("model\nloss %", True),
               ("model\ndelay", True), ("transp.\np99", True), ("transp.\nmax", True),
               ("model\nqueue", True), ("queue\np99", True)]  # fmt: skip
    title = ("per link: its writers' messages and their bytes on the wire, against its bandwidth; versions "
             "its readers never received, beside the modelled loss and drops; its buffers' transport in µs "
             "(the largest p99 and max) beside the modelled mean delay; the wait for its transmitter (the "
             "transport less latency and wire time, largest p99) beside the model's longest")
    return make_table(title, columns, rows)


def chain_table(report: RunReport, window: WindowReport | None = None) -> Table:
    """Per chain: from the head's send to the start of the tail's computation."""
    rows = []
    for c in (window or report).chains:
        lat = c.latency_us
        rows.append(
            [c.name, " -> ".join(c.processes), str(c.samples), num(lat.p50), num(lat.p99), num(lat.max),
             str(c.broken)]
        )  # fmt: skip
    columns = [("chain", False), ("processes", False), ("samples", True), ("p50", True), ("p99", True),
               ("max", True), ("broken", True)]  # fmt: skip
    return make_table("per chain: end-to-end latency in µs (head's send -> tail's first use)", columns, rows)


def fault_table(report: RunReport, window: WindowReport | None = None) -> Table:
    rows = []
    for f in (window or report).faults:
        chain = " -> ".join(f.chain)
        rows.append(
            [
                f.kind,
                f.process or "-",
                ",".join(map(str, f.dpus)) if f.dpus else "-" if f.dpu is None else str(f.dpu),
                f.buffer or "-",
                f.writer or "-",
                "-" if f.cycle is None else str(f.cycle),
                f"{chain}\n{f.detail}" if chain else f.detail,
            ]
        )
    columns = [("kind", False), ("process", False), ("DPU", True), ("buffer", False), ("writer", False),
               ("cycle", True), ("chain / detail", False)]  # fmt: skip
    return make_table("faults", columns, rows)


def _beside(b: Beside, digits: int = 1, none: str = "unknown") -> list[str]:
    """predicted, measured, Δ; NONE says why there is no prediction: a worst that bounds
    nothing is unbounded, a figure that follows from how often the host sends an event unknown."""
    return [num(b.predicted, digits) if b.predicted is not None else none, num(b.measured, digits),
            signed(b.delta, digits)]


OUTSIDE = ("out-\nside", False)


def _flag(b: Beside) -> str:
    return "!" if b.outside else "-"


def predicted_tables(p: Predicted) -> list[Table]:
    """Each predicted figure beside the measured one, with the delta (measured - predicted)
    and `!` where the measured value is outside its prediction."""
    title = (f"predicted (from the system file alone) beside measured, generation {p.generation}: per DPU "
             f"(! beyond ±{p.compute_points:g} points)")
    columns = [("DPU", True), ("% comp\npred.", True), ("% comp\nmeas.", True), ("Δ", True)]
    # the links' charged costs beside the measured % communicate, where a link charges any
    charged = any(d.communicate_pct.predicted is not None for d in p.dpus)
    if charged:
        columns += [("% comm\npred.", True), ("% comm\nmeas.", True), ("Δ", True)]
    tables = [make_table(title, [*columns, OUTSIDE], [
        [str(d.id), *_beside(d.compute_pct), *(_beside(d.communicate_pct, 1, "-") if charged else []),
         "!" if d.compute_pct.outside or d.communicate_pct.outside else "-"] for d in p.dpus])]
    rows = [[r.name, str(r.dpu), *_beside(r.response_us, 0, "unbounded"), num(r.response_max_us, 0),
             f"paced by {r.paced_by}" if r.paced_by else _flag(r.response_us)] for r in p.processes]
    tables.append(make_table(
        f"per process: worst response predicted, p99 measured, µs (! more than late_pct, {p.late_pct} % of "
        "the period, above)",
        [("process", False), ("DPU", True), ("worst\npred.", True), ("p99\nmeas.", True), ("Δ", True),
         ("max\nmeas.", True), OUTSIDE], rows))
    if p.inputs:
        rows = [[f"{i.reader} <- {i.buffer} ({i.writer})", *_beside(i.new, 2), *_beside(i.dropped, 2),
                 "!" if i.new.outside or i.stale.outside or i.dropped.outside else "-"] for i in p.inputs]
        tables.append(make_table(
            f"per input: share of the reader's cycles with new data, sequences dropped per cycle "
            f"(! beyond ±{p.share:g})",
            [("reader <- buffer (writer)", False), ("new\npred.", True), ("new\nmeas.", True), ("Δ", True),
             ("dropped\npred.", True), ("dropped\nmeas.", True), ("Δ", True), OUTSIDE], rows))
    if p.chains:
        rows = [[c.name, num(c.best_us, 0), *_beside(c.latency_us, 0, "unbounded"),
                 num(c.latency_max_us, 0),
                 _flag(c.latency_us)] for c in p.chains]
        tables.append(make_table(
            f"per chain: latency predicted best and worst, measured p99, µs (! more than late_pct, "
            f"{p.late_pct} % of the tail's period, above)",
            [("chain", False), ("best\npred.", True), ("worst\npred.", True), ("p99\nmeas.", True),
             ("Δ", True), ("max\nmeas.", True), OUTSIDE], rows))
    tables += _network_tables(p)
    return tables


def _network_tables(p: Predicted) -> list[Table]:
    """Where a link's transport is emulated (latency, jitter, loss): what it models beside what was
    measured, per input and per chain."""
    emulated = [i for i in p.inputs if i.transport_us.predicted or i.lost_pct.predicted]
    if not emulated:
        return []
    rows = [[f"{i.reader} <- {i.buffer} ({i.writer})", *_beside(i.transport_us, 0), *_beside(i.lost_pct, 2)]
            for i in emulated]
    tables = [make_table(
        "per input: the link's emulated transport, mean delay modelled beside the measured p50 transport "
        "(µs, the platform's own adds) and % of the writer's buffers lost",
        [("reader <- buffer (writer)", False), ("delay\nmodel", True), ("p50\nmeas.", True), ("Δ", True),
         ("% lost\nmodel", True), ("% lost\nmeas.", True), ("Δ", True)], rows)]
    rows = [[c.name, *_beside(c.network_us, 0)] for c in p.chains if c.network_us.predicted]
    if rows:
        tables.append(make_table(
            "per chain: how much of its latency is the network, the links' mean emulated delays beside the "
            "sum of its buffers' measured p50 transport, µs",
            [("chain", False), ("network\nmodel", True), ("network\nmeas.", True), ("Δ", True)], rows))
    return tables


def predicted_lines(p: Predicted) -> list[str]:
    """What is outside its prediction, one line each, or that nothing is."""
    return p.outside or [f"every measured figure is within its prediction: {PLATFORM} stayed within the "
                         "tolerances"]


def window_header(window: WindowReport) -> str:
    duration = window.duration_ms
    span = "no measured cycle" if duration is None else f"{duration / 1000:.3f} s"
    return f"== generation {window.generation} window: {span} =="


def malformed_line(malformed: dict[str, int]) -> str:
    """The messages (and records) skipped as malformed, per channel: `skel report` and `skel
    watch` say it in the same words."""
    return "malformed messages skipped: " + ", ".join(f"{c}: {n}" for c, n in malformed.items())


def damage_lines(report: RunReport) -> list[str]:
    """What the reader could not use, in one line each (none for a clean log)."""
    integ = report.integrity
    lines = []
    if integ.damaged:
        lost = sum(b["to_seq"] - b["from_seq"] + 1 for b in integ.lost_batches)
        lines.append(
            f"log damaged: {len(integ.corrupt_ranges)} corrupt ranges ({integ.corrupt_bytes} bytes), "
            f"{lost} timing batches lost; the tables use everything else"
        )
    if integ.malformed:
        lines.append(malformed_line(integ.malformed))
    if integ.unauthenticated:
        lines.append(f"{integ.unauthenticated} messages failed the key check (unsigned, forged or replayed): "
                     "left out, the tables use the genuine ones")
    if integ.signed and not integ.checked:
        lines.append("the run was signed, but not checked here: give its key (--key FILE or $SKEL_KEY_FILE) "
                     "to use only its genuine messages")
    return lines


def stopped_lines(report: RunReport) -> list[str]:
    """That a command ended the run early, in one line (none for a run that ran its course)."""
    stop = report.stopped
    if stop is None:
        return []
    what = "the run was" if stop.dpu < 0 else f"DPU {stop.dpu} of the run was"
    return [f"{what} stopped at {stop.at_s:.2f} s of its planned {stop.planned_s:g} s "
            f"({stop.command} from {stop.sender}): the tables cover what ran"]


def faithful_lines(report: RunReport) -> list[str]:
    """A DPU that could not model what was asked, in one line each (none for a faithful run)."""
    return [f"DPU {dpu} is not faithful: its tasking threads got no SCHED_FIFO priority or no pinning "
            "to one CPU (its log says which), so the kernel's time sharing stood in for fixed-priority "
            "preemptive scheduling" for dpu in report.not_faithful]


def print_report(
    report: RunReport, console: Console | None = None, paper: dict[Any, Any] | None = None
) -> None:
    console = console or output_console()
    windows: list[WindowReport | None] = list(report.windows) if len(report.windows) > 1 else [None]
    for window in windows:
        if window is not None:
            console.print(window_header(window), style="bold", markup=False, highlight=False)
        part = window or report
        console.print(dpu_table(report, window))
        if paper:
            console.print(paper_table(report, paper, window))
        console.print(process_table(report, window))
        console.print(response_table(report, window))
        if any(p.varying for p in part.processes):
            console.print(compute_table(report, window))
        if any(p.events for p in part.processes):
            console.print(event_table(report, window))
        if any(p.inputs for p in part.processes):
            console.print(input_table(report, window))
        if any(b.readers for b in part.buffers):
            console.print(buffer_table(report, window))
        if part.links:
            console.print(link_table(report, window))
        if part.chains:
            console.print(chain_table(report, window))
        if part.faults:
            console.print(fault_table(report, window))
    if report.predicted is not None:
        for table in predicted_tables(report.predicted):
            console.print(table)
        for line in predicted_lines(report.predicted):
            console.print(line, style="yellow" if report.predicted.outside else None, markup=False,
                          highlight=False)
    for line in stopped_lines(report) + faithful_lines(report) + damage_lines(report):
        console.print(line, style="yellow", markup=False, highlight=False)
