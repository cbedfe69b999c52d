"""What `skel watch` draws: per-DPU utilization bars, per-process overruns and release
latency (the live tables, analysis/measure/tally.py), faults as they were found (rich
renderables, no terminal I/O here)."""

from __future__ import annotations

from typing import Any, Protocol

from rich.console import Console, ConsoleOptions, Group, RenderResult
from rich.measure import Measurement
from rich.table import Table
from rich.text import Text

from skeleton.analysis.measure.tally import GenerationTally
from skeleton.analysis.views.tables import malformed_line

from ..live.listener import STATE_NAMES, RecordStore


class Heard(Protocol):
    """What the view shows of what was heard (watch.Heard)."""

    run_id: int | None
    store: RecordStore | None
    latest: dict[int, Any]
    tables: GenerationTally | None
    lost_batches: int
    skipped: dict[str, int]
    covered: int
    faults: list[tuple[float, str]]

BAR_WIDTH = 40  # cells, when the terminal has room
MIN_BAR_WIDTH = 10  # what the bar gives up before the figures beside it are cut
SHARES = (("compute", "green"), ("communicate", "cyan"), ("wait", "grey50"), ("overhead", "red"))


class Bar:
    """compute / communicate / wait / overhead as one stacked bar, as wide as its column lets
    it be: on a narrow terminal the bar shrinks, not the DPU ids and percentages."""

    def __init__(self, shares: list[float | None]) -> None:
        self.shares = shares

    def __rich_measure__(self, console: Console, options: ConsoleOptions) -> Measurement:
        return Measurement(MIN_BAR_WIDTH, BAR_WIDTH)

    def __rich_console__(self, console: Console, options: ConsoleOptions) -> RenderResult:
        yield self.text(max(MIN_BAR_WIDTH, min(BAR_WIDTH, options.max_width)))

    def text(self, width: int) -> Text:
        bar = Text()
        if any(s is None for s in self.shares):
            return bar.append("·" * width, style="grey30")
        cells = [max(0.0, float(s or 0.0)) * width / 100.0 for s in self.shares]
        used = 0
        for (_, style), cell in zip(SHARES, cells, strict=True):
            n = min(width - used, round(cell))
            bar.append("█" * n, style=style)
            used += n
        return bar.append(" " * (width - used))


def _num(value: float | None, digits: int = 1) -> str:
    return "-" if value is None else f"{value:.{digits}f}"


def render(heard: Heard, url: str) -> Group:
    if heard.store is None:
        dpus = ", ".join(f"DPU {d} {STATE_NAMES.get(s.state, s.state)}"
                         for d, s in sorted(heard.latest.items()))
        return Group(Text(f"skel watch {url}: waiting for a run" + (f" ({dpus})" if dpus else "")))
    tables = heard.tables
    head = Text(f"run {heard.run_id}")
    if tables is not None:
        # After a live switch the tables are the new generation's window, timed from its start:
        # said so, or its time read as the run's, begun again.
        earlier = sorted(g for g in heard.store.generations if g < tables.generation)
        switched = f" (switched live from {earlier[-1]}; `skel report` has every window)" if earlier else ""
        head.append(f" · {tables.system.name} · generation {tables.generation}{switched} · measured "
                    f"{tables.elapsed_ms / 1000:.1f} s · {heard.store.n_records} records · "
                    f"{heard.lost_batches} batches lost")
        if heard.store.n_records > heard.covered:
            head.append(f" · faults searched in the first {heard.covered}", style="yellow")
        if heard.store.unread:  # the search fell behind the records by more than the store holds
            head.append(f" · {heard.store.unread} records forgotten unsearched", style="yellow")
    else:
        head.append(" · waiting for its config_t")
    parts: list[Any] = [head]
    if heard.skipped:  # left out of the tables: said so, in `skel report`'s words
        parts.append(Text(malformed_line(heard.skipped), style="yellow"))
    if tables is not None:
        parts += [_dpu_view(heard, tables), _process_view(tables)]
    legend = Text("bars: ")
    for name, style in SHARES:
        legend.append("█ ", style=style).append(f"{name}  ")
    parts.append(legend)
    faults = Table(title="faults as they happen (s since the run was first heard)", show_header=False)
    faults.add_column(justify="right")
    faults.add_column()
    for at, text in heard.faults[-8:]:
        faults.add_row(f"{at:.1f}", text)
    parts.append(faults if heard.faults else Text("faults: none so far"))
    return Group(*parts)


def _dpu_view(heard: Heard, tables: GenerationTally) -> Table:
    table = Table(title="per DPU: utilization so far (warm-up excluded)")
    for name, justify in (("DPU", "right"), ("state", "left"), ("utilization", "left"), ("% comp", "right"),
                          ("% comm", "right"), ("% wait", "right"), ("% ovhd", "right"), ("ovr", "right"),
                          ("records", "right")):  # fmt: skip
        # The bar's column is the one rich may narrow (to the bar's least width): the others keep
        # their figures whole.
        table.add_column(name, justify=justify, no_wrap=name != "utilization")  # type: ignore[arg-type]
    for d in tables.dpus:
        shares = list(d.shares_pct)
        status = heard.latest.get(d.id)
        state = "-" if status is None else STATE_NAMES.get(status.state, str(status.state))
        table.add_row(str(d.id), state, Bar(shares), *(_num(s) for s in shares), str(d.overruns),
                      str(d.records))
    return table


def _process_view(tables: GenerationTally) -> Table:
    table = Table(title="per process: release latency (µs) and overruns so far")
    for name in ("process", "DPU", "cycles", "ovr", "p50", "p99", "max", "late/too late"):
        table.add_column(name, justify="left" if name == "process" else "right", no_wrap=True)
    for p in tables.processes:
        lat = p.latency_us
        ovr = Text(str(p.overruns), style="bold red" if p.overruns else "")
        table.add_row(p.name, str(p.dpu), str(p.cycles), ovr, _num(lat.p50), _num(lat.p99), _num(lat.max),
                      f"{p.late}/{p.too_late}")
    return table
