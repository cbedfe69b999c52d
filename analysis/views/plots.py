"""PNG figures of one run (`skel report RUN --plots DIR`, with report.html from html.py).

Every number plotted comes from the report (metrics.py, latency.py, chains.py: the
same definitions as the tables) or, for the timeline, straight from the timing
records. Figures are drawn with matplotlib's Agg backend (no display needed).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # before pyplot: files only, never a window

import matplotlib.pyplot as plt
import numpy as np
from matplotlib.figure import Figure
from matplotlib.patches import Patch
from matplotlib.ticker import FuncFormatter, LogLocator, NullFormatter

from ..measure.faults import first_release_ns
from ..measure.metrics import LatencyUs, ProcessMetrics, cycle_end_ns, frames, measured
from ..measure.run import RunAnalysis
from ..read.records import FLAG_OVERRUN, FLAG_SKIPPED

DPI = 100
COMPUTE, COMMUNICATE, WAIT, OVERHEAD = "#4C72B0", "#DD8452", "#C8C8C8", "#C44E52"
COMM_IN, COMM_OUT, BLOCKED = "#F2B37E", "#B8561B", "#8C8C8C"
OVERRUN = "#D62728"


# Section heading and caption of each plot in report.html.
TEXT = {
    "utilization": ("Utilization per DPU", "Share of each DPU's measured time, with the configured "
                    "(static) load Σ compute/period beside it."),
    "timeline": ("Timeline of process phases", ""),
    "schedule": ("How far behind its schedule each DPU ran",
                 "The lateness of each minor cycle's first start (its release latency) over the run, "
                 "against one minor cycle (dashed): above it the DPU runs cycles of the past. Faults "
                 "`behind` are shaded (red: the design's, orange: the platform's), stalls are grey bars."),
    "release_latency": ("Release latency per process",
                        "Start minus release of every measured cycle (log-scale counts), with p50 and p99."),
    "event_latency": ("Event latency per process", "For each process awaiting an event: its start minus "
                      "the event's arrival at its DPU, every measured cycle (log-scale counts), with p50 "
                      "and p99."),
    "buffer_latency": ("Buffer transport latency", "Receive minus send time of every new message, "
                       "per buffer and reader (log-scale counts)."),
    "chain_latency": ("Chain latency over time", "Per value reaching the chain's tail: its first use "
                      "there minus its send time at the head."),
}  # fmt: skip


@dataclass
class Plot:
    name: str  # file name, e.g. utilization.png
    title: str  # section heading in report.html
    caption: str


@dataclass
class PlotSet:
    plots: list[Plot] = field(default_factory=list)
    notes: list[str] = field(default_factory=list)  # what was skipped, and why


def write_plots(data: RunAnalysis, out_dir: Path, window_ms: tuple[float, float] | None = None) -> PlotSet:
    """Every figure as out_dir/NAME.png. `window_ms` = (start, length) of the timeline,
    in ms after the measured window's start (default: 4 minor cycles of the slowest DPU)."""
    made = PlotSet()

    def save(fig: Figure, plot: Plot) -> None:
        fig.savefig(out_dir / plot.name, dpi=DPI)
        plt.close(fig)
        made.plots.append(plot)

    save(utilization(data), Plot("utilization.png", *TEXT["utilization"]))
    fig, caption = timeline(data, window_ms)
    save(fig, Plot("timeline.png", TEXT["timeline"][0], caption))
    save(schedule(data), Plot("schedule.png", *TEXT["schedule"]))
    save(release_latency(data), Plot("release_latency.png", *TEXT["release_latency"]))
    fig = event_latency(data)
    if fig is not None:
        save(fig, Plot("event_latency.png", *TEXT["event_latency"]))
    fig = buffer_latency(data)
    if fig is None:
        made.notes.append("Buffer latency: no buffer has a reader with a measured sample.")
    else:
        save(fig, Plot("buffer_latency.png", *TEXT["buffer_latency"]))
    fig = chain_latency(data)
    if fig is None:
        made.notes.append(
            "Chain latency: the system file names no chains (`chains: [[head, ..., tail]]`)."
            if not data.system.chains
            else "Chain latency: no value travelled a whole chain in the measured window."
        )
    else:
        save(fig, Plot("chain_latency.png", *TEXT["chain_latency"]))
    return made


def _figure(width: float, height: float) -> Figure:
    return plt.figure(figsize=(width, height), layout="constrained")


def _title(data: RunAnalysis, what: str) -> str:
    rep = data.report
    return f"{rep.system}, run {rep.run_id}: {what}"


# --- utilization -----------------------------------------------------------------------


def utilization(data: RunAnalysis) -> Figure:
    dpus = data.report.dpus
    fig = _figure(max(6.0, 1.6 * len(dpus) + 2.5), 4.6)
    ax = fig.add_subplot()
    x = np.arange(len(dpus))
    parts = [
        ("compute", COMPUTE, [d.compute_pct for d in dpus]),
        ("communicate", COMMUNICATE, [d.communicate_pct for d in dpus]),
        ("wait", WAIT, [d.wait_pct for d in dpus]),
        ("overhead", OVERHEAD, [d.overhead_pct for d in dpus]),
    ]
    bottom = np.zeros(len(dpus))
    for label, color, values in parts:
        v = np.clip(np.array([0.0 if p is None else p for p in values]), 0, None)
        bars = ax.bar(x - 0.15, v, 0.5, bottom=bottom, color=color, label=f"% {label}", edgecolor="white")
        for bar, value in zip(bars, v, strict=True):
            if value >= 6:
                ink = "black" if color == WAIT else "white"
                ax.text(bar.get_x() + bar.get_width() / 2, bar.get_y() + value / 2, f"{value:.1f}",
                        ha="center", va="center", fontsize=8, color=ink)  # fmt: skip
        bottom += v
    for xi, d in zip(x, dpus, strict=True):
        if d.compute_pct is None:
            ax.text(xi - 0.15, 2, "no measured\ncycle", ha="center", va="bottom", fontsize=8, color="#555")
    load = np.array([d.static_load_pct for d in dpus])
    ax.bar(x + 0.3, load, 0.2, color="none", edgecolor="black", hatch="///",
           label="configured load\n(Σ compute / period)")  # fmt: skip
    for xi, value in zip(x, load, strict=True):
        ax.text(xi + 0.3, value + 1, f"{value:.1f}", ha="center", va="bottom", fontsize=8)
    ax.axhline(100, color="black", linewidth=0.6, linestyle=":")
    ax.set_xticks(x, [f"DPU {d.id}\n{d.configured_cycle_ms:g} ms cycle" for d in dpus])
    ax.set_ylabel("% of measured time")
    ax.set_ylim(0, max(110.0, float(load.max(initial=0)) * 1.1))
    ax.legend(loc="upper left", bbox_to_anchor=(1.0, 1.0), fontsize=9, frameon=False)
    ax.set_title(_title(data, "utilization per DPU (bars sum to 100 %)"))
    return fig


# --- timeline --------------------------------------------------------------------------


def _host_ns(data: RunAnalysis, recs: np.ndarray, field_ns: np.ndarray) -> np.ndarray:
    return data.clock.to_host_many(recs["dpu"], field_ns)


def default_window_ns(data: RunAnalysis) -> tuple[int, int]:
    """From the moment every process is past warm-up, 4 minor cycles of the slowest DPU: in the
    report generation's window, whose config names the timeline's rows."""
    recs = data.records
    in_window = recs[measured(recs, data.system)]
    use = in_window if len(in_window) else recs
    if not len(use):
        return 0, 1
    release = _host_ns(data, use, use["release_ns"])
    firsts = [release[use["process"] == p].min() for p in np.unique(use["process"]).tolist()]
    slowest_us = max((d.minor_cycle_us for d in data.system.dpus), default=5000)
    return int(max(firsts)), int(4 * slowest_us * 1000)


def timeline(data: RunAnalysis, window_ms: tuple[float, float] | None = None) -> tuple[Figure, str]:
    """A Gantt of every process's phases over a short window of the report's generation, one
    row per process of its config."""
    start, length = default_window_ns(data)
    if window_ms is not None:
        start, length = start + int(window_ms[0] * 1e6), int(window_ms[1] * 1e6)
    recs = data.records
    begin = _host_ns(data, recs, recs["start_ns"])
    end = _host_ns(data, recs, cycle_end_ns(recs))
    shown = recs[(end >= start) & (begin <= start + length)]
    names = data.process_names()
    dpus = sorted(data.system.dpus, key=lambda d: d.id)
    rows = {d.id: sorted(data.system.processes_on(d.id), key=lambda p: (p.order, p.id)) for d in dpus}
    heights = [max(1, len(rows[d.id])) + 0.6 for d in dpus]
    fig = _figure(11, 1.0 + 0.42 * sum(heights))
    grid = fig.subplots(len(dpus), 1, sharex=True, gridspec_kw={"height_ratios": heights}, squeeze=False)
    axes = grid[:, 0]
    overruns = 0
    for ax, dpu in zip(axes, dpus, strict=True):
        procs = rows[dpu.id]
        for y, proc in enumerate(procs):
            mine = shown[shown["process"] == proc.id]
            t = (_host_ns(data, mine, mine["start_ns"]) - start) / 1e6
            offset = np.zeros(len(mine))
            for field_name, color in (("comm_in_ns", COMM_IN), ("blocked_ns", BLOCKED),
                                      ("compute_ns", COMPUTE), ("comm_out_ns", COMM_OUT)):  # fmt: skip
                width = mine[field_name] / 1e6
                ax.broken_barh(list(zip(t + offset, width, strict=True)), (y - 0.35, 0.7), facecolors=color)
                offset += width
            rel = (_host_ns(data, mine, mine["release_ns"]) - start) / 1e6
            ax.plot(rel, np.full(len(rel), y - 0.47), marker="v", linestyle="none", color="black",
                    markersize=3.5)  # fmt: skip
            late = ((mine["flags"] & FLAG_OVERRUN) != 0) | (mine["slack_ns"] < 0)
            late &= (mine["flags"] & FLAG_SKIPPED) == 0
            overruns += int(np.count_nonzero(late))
            for t0, w in zip(t[late], offset[late], strict=True):
                ax.add_patch(plt.Rectangle((t0, y - 0.42), max(w, 0.05), 0.84, fill=False, edgecolor=OVERRUN,
                                           linewidth=1.6))  # fmt: skip
        ax.set_yticks(range(len(procs)), [names.get(p.id, str(p.id)) for p in procs], fontsize=8)
        ax.set_ylim(len(procs) - 0.4, -0.7)
        ax.set_ylabel(f"DPU {dpu.id}", rotation=0, ha="right", va="center", fontweight="bold")
        ax.grid(axis="x", color="#E0E0E0", linewidth=0.6)
        ax.set_axisbelow(True)
    axes[-1].set_xlim(0, length / 1e6)
    shift = f" + {window_ms[0]:g} ms" if window_ms and window_ms[0] else ""
    axes[-1].set_xlabel(f"time (ms) from the end of warm-up{shift}, host clock")
    legend = [Patch(color=COMM_IN, label="comm in"), Patch(color=BLOCKED, label="blocked (data wait)"),
              Patch(color=COMPUTE, label="compute"), Patch(color=COMM_OUT, label="comm out"),
              plt.Line2D([], [], marker="v", linestyle="none", color="black", markersize=4, label="release"),
              Patch(facecolor="none", edgecolor=OVERRUN, linewidth=1.6, label="overrun")]  # fmt: skip
    fig.legend(handles=legend, loc="outside lower center", ncols=6, fontsize=8, frameon=False)
    axes[0].set_title(_title(data, f"process phases, {length / 1e6:.1f} ms window"))
    caption = (f"{length / 1e6:.1f} ms from the end of warm-up on the host clock; idle time is blank; "
               f"{overruns} overrun cycle(s) outlined in red in this window.")  # fmt: skip
    return fig, caption


# --- histograms --------------------------------------------------------------------------


def _grid(n: int, width: float = 11.0, row_height: float = 2.3) -> tuple[Figure, list[plt.Axes]]:
    cols = min(3, n)
    rows = -(-n // cols)
    fig = _figure(width, 0.9 + row_height * rows)
    axes = list(fig.subplots(rows, cols, squeeze=False).ravel())
    for ax in axes[n:]:
        ax.set_visible(False)
    return fig, axes[:n]


def _log_counts(ax: plt.Axes, highest: int) -> None:
    """Log-scale counts labelled 1, 2, 5, 10... (not 6x10^0), from 1 up."""
    ax.set_yscale("log")
    ax.set_ylim(0.7, max(highest, 1) * 1.8)
    ax.yaxis.set_major_locator(LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
    ax.yaxis.set_major_formatter(FuncFormatter(lambda v, _: f"{v:g}"))
    ax.yaxis.set_minor_formatter(NullFormatter())


def schedule(data: RunAnalysis) -> Figure:
    """Per DPU: each minor cycle's frame release latency over the report generation's window
    (the whole run for one generation), with the faults `behind` and `stall` of the report
    marked where they happened: the time axis counts from the run's first release, as their
    at_s does."""
    dpus = sorted(data.system.dpus, key=lambda d: d.id)
    fig = _figure(11, 1.0 + 1.6 * len(dpus))
    axes = fig.subplots(len(dpus), 1, sharex=True, squeeze=False)[:, 0]
    recs = data.records
    origin = first_release_ns(data.recorded.records)
    for ax, dpu in zip(axes, dpus, strict=True):
        mine = recs[recs["dpu"] == dpu.id]
        if len(mine) == 0:
            ax.text(0.5, 0.5, "no cycle", ha="center", va="center", transform=ax.transAxes)
            continue
        _, starts, releases = frames(mine)
        ax.plot((releases - origin[dpu.id]) / 1e9, (starts - releases) / 1e6, color=COMPUTE, linewidth=0.8)
        ax.axhline(dpu.minor_cycle_us / 1000, color="black", linestyle="--", linewidth=0.8)
        for f in data.report.faults:
            if f.kind == "behind" and f.dpu == dpu.id and f.at_s is not None and f.duration_ms is not None:
                ax.axvspan(f.at_s, f.at_s + f.duration_ms / 1000, color=OVERRUN if f.fatal else COMM_IN,
                           alpha=0.3, linewidth=0)  # fmt: skip
            if f.kind == "stall" and dpu.id in f.dpus and f.at_s is not None and f.duration_ms is not None:
                end = f.at_s + max(f.duration_ms / 1000, 0.01)
                ax.axvspan(f.at_s, end, color=WAIT, alpha=0.8, linewidth=0)
        ax.set_ylabel(f"DPU {dpu.id}\nms late", fontsize=8)
        ax.grid(color="#E0E0E0", linewidth=0.6)
    axes[-1].set_xlabel("time (s) from the run's first release, each DPU's clock")
    axes[0].set_title(_title(data, "lateness of each minor cycle's first start"))
    return fig


def release_latency(data: RunAnalysis) -> Figure:
    procs = [p for p in data.report.processes if p.histograms.get("release_latency_us", None)]
    return _latency_grid(data, [(p, p.latency_us) for p in procs], "release_latency_us", "release latency",
                         "release latency (start - release) per process")


def event_latency(data: RunAnalysis) -> Figure | None:
    procs = [p for p in data.report.processes if p.events is not None and p.events.handled]
    if not procs:
        return None
    return _latency_grid(data, [(p, p.events.latency_us) for p in procs if p.events is not None],
                         "event_latency_us", "event latency", "event latency (start - event) per process")


def _latency_grid(data: RunAnalysis, procs: list[tuple[ProcessMetrics, LatencyUs]], key: str, what: str,
                  title: str) -> Figure:
    """One histogram per process of its measured cycles' `key`, with p50 and p99."""
    fig, axes = _grid(max(1, len(procs)))
    for ax, (p, stats) in zip(axes, procs, strict=False):
        hist = p.histograms[key]
        ax.set_title(f"{p.name} (DPU {p.dpu}, {p.period_us / 1000:g} ms)", fontsize=9)
        if not hist.counts:
            ax.text(0.5, 0.5, "no measured cycle", ha="center", va="center", transform=ax.transAxes)
            ax.set_xticks([])
            ax.set_yticks([])
            continue
        ax.stairs(hist.counts, hist.bins, fill=True, color=COMPUTE)
        _log_counts(ax, max(hist.counts))
        for value, style, label in ((stats.p50, "--", "p50"), (stats.p99, ":", "p99")):
            if value is not None:
                ax.axvline(value, color="black", linestyle=style, linewidth=1,
                           label=f"{label} {value:.0f} µs")  # fmt: skip
        ax.legend(fontsize=7, frameon=False)
        ax.tick_params(labelsize=8)
    for ax in axes:
        ax.set_xlabel(f"{what} (µs)", fontsize=8)
    for ax in axes[:: min(3, len(axes))]:
        ax.set_ylabel("cycles", fontsize=8)
    fig.suptitle(_title(data, title))
    return fig


def buffer_latency(data: RunAnalysis) -> Figure | None:
    buffers = [b for b in data.report.buffers if any(r.samples for r in b.readers)]
    if not buffers:
        return None
    fig, axes = _grid(len(buffers))
    colors = plt.get_cmap("tab10").colors
    for ax, b in zip(axes, buffers, strict=True):
        for color, reader in zip(colors, (r for r in b.readers if r.samples), strict=False):
            ax.stairs(reader.histogram.counts, reader.histogram.bins, color=color, linewidth=1.4,
                      label=f"→ {reader.process} (p99 {reader.latency_us.p99:.0f} µs)")  # fmt: skip
        _log_counts(ax, max(max(r.histogram.counts, default=0) for r in b.readers))
        ax.set_title(f"{b.buffer} ({b.writer} →)", fontsize=9)
        ax.set_xlabel("send → receive (µs)", fontsize=8)
        ax.legend(fontsize=7, frameon=False)
        ax.tick_params(labelsize=8)
    for ax in axes[:: min(3, len(axes))]:
        ax.set_ylabel("messages", fontsize=8)
    fig.suptitle(_title(data, "buffer transport latency per reader"))
    return fig


# --- chains ------------------------------------------------------------------------------


def chain_latency(data: RunAnalysis) -> Figure | None:
    """One row per chain (they often overlap), latency of every value over time."""
    chains = [c for c in data.report.chains if c.series is not None and len(c.series.latency_ns)]
    if not chains:
        return None
    fig = _figure(11, 1.2 + 2.1 * len(chains))
    axes = fig.subplots(len(chains), 1, sharex=True, squeeze=False)[:, 0]
    t0 = min(int(c.series.use_ns.min()) for c in chains if c.series is not None)
    colors = plt.get_cmap("tab10").colors
    for ax, color, c in zip(axes, colors, chains, strict=False):
        assert c.series is not None
        t = (c.series.use_ns - t0) / 1e9
        ms = c.series.latency_ns / 1e6
        ax.plot(t, ms, marker=".", markersize=3, linewidth=0.5, color=color)
        lat = c.latency_us
        for value, style, label in ((lat.p50, "--", "p50"), (lat.p99, ":", "p99")):
            if value is not None:
                ax.axhline(value / 1000, color="black", linestyle=style, linewidth=0.8,
                           label=f"{label} {value / 1000:.2f} ms")  # fmt: skip
        ax.set_title(f"{' → '.join(c.processes)} ({c.samples} values, {c.broken} broken)", fontsize=9)
        ax.set_ylabel("latency (ms)", fontsize=9)
        ax.set_ylim(0, max(float(ms.max()) * 1.1, 1e-3))
        ax.grid(color="#E0E0E0", linewidth=0.6)
        ax.legend(fontsize=8, loc="lower right", frameon=True, framealpha=0.8)
    axes[-1].set_xlabel("time since the first measured value reached a tail (s)")
    fig.suptitle(_title(data, "end-to-end chain latency (head's send → first use at the tail)"))
    return fig
