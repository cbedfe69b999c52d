"""The prediction as tables: `skel check` prints one, `skel allocate` two side by side."""

from __future__ import annotations

import math

from rich.console import Console
from rich.table import Table

from ..theory.predict import Prediction


def _ms(us: float | None, digits: int = 3) -> str:
    return "unbounded" if us is None or math.isinf(us) else f"{us / 1000:.{digits}g}"


def _known(value: float | None, spec: str) -> str:
    """A figure that depends on how often the host sends an event is unknown (predict.py)."""
    return "unknown" if value is None else f"{value:{spec}}"


def _table(*columns: str) -> Table:
    table = Table(box=None, pad_edge=False)
    for i, c in enumerate(columns):
        left = i == 0 or c.startswith("processes") or c == "frames that overflow"
        table.add_column(c, justify="left" if left else "right")
    return table


def print_prediction(console: Console, pred: Prediction) -> None:
    console.print("[bold]prediction[/] (from the file alone: the platform's own costs come on top)")
    # the links' costs the DPUs charge (model.charges()), in their own columns when there are any
    charged = any(p.communicate_us for p in pred.processes)
    dpus = _table("DPU", "executive", "load %", "predicted % compute",
                  *(["predicted % communicate"] if charged else []), "frames that overflow", "lockout at ms")
    for d in pred.dpus:
        over = ", ".join(f"{f.first} ({_ms(f.demand_us + f.wait_us, 4)} of {f.minor_cycle_us / 1000:g} ms)"
                         for f in d.overflowing[:3]) + (" ..." if len(d.overflowing) > 3 else "")
        # only at long draws: said apart from the certain ones, with its worst
        maybe = ", ".join(f"{f.first} may ({_ms(f.worst_demand_us + f.worst_wait_us, 4)} of "
                          f"{f.minor_cycle_us / 1000:g} ms)" for f in d.may_overflow[:3])
        over = ", ".join(x for x in (over, maybe) if x)
        load = f"[red]{d.load_pct:.1f}[/]" if not d.schedulable else f"{d.load_pct:.1f}"
        dpus.add_row(str(d.id), "tasking" if d.executive == "threads" else "cyclic", load,
                     _known(d.compute_pct, ".1f"),
                     *([_known(d.communicate_pct, ".1f")] if charged else []), over or "-",
                     f"{d.lockout_ms:.0f}" if d.lockout_ms else "-")
    console.print(dpus)
    procs = _table("process", "DPU", "period ms", "compute ms", *(["communicate ms"] if charged else []),
                   "runs Hz", "start ms", "worst response ms")
    for p in pred.processes:
        resp = _ms(p.response_us)
        resp = resp if p.schedulable else f"[red]{resp}[/]"
        paced = f" (paced by {p.paced_by})" if p.paced_by else ""
        # a DPU that falls ever further behind starts its processes ever later
        start = f"{_ms(p.start_min_us)}..{_ms(p.start_max_us)}" if p.response_us is not None else "-"
        procs.add_row(p.name + paced, str(p.dpu), f"{p.period_us / 1000:g}", f"{p.compute_us / 1000:.4g}",
                      *([f"{p.communicate_us / 1000:.4g}"] if charged else []), _known(p.rate_hz, ".4g"),
                      start, resp)
    console.print(procs)
    mixed = [i for i in pred.inputs if i.stale is None or i.dropped is None or i.stale > 0.005
             or i.dropped > 0.005]
    if mixed:
        inputs = _table("reader <- buffer (writer)", "new", "stale", "dropped per cycle")
        for i in mixed:
            inputs.add_row(f"{i.reader} <- {i.buffer} ({i.writer})", _known(i.new, ".2f"),
                           _known(i.stale, ".2f"), _known(i.dropped, ".2f"))
        console.print(inputs)
    else:
        console.print("every input: new data each reader cycle, none stale or dropped")
    if pred.chains:
        chains = _table("chain", "best ms", "worst ms")
        for c in pred.chains:
            chains.add_row(" -> ".join(c.processes), _ms(c.best_us), _ms(c.worst_us))
        console.print(chains)
    emulated = any(link.delay_us[2] or link.lost_pct or link.queue_us for link in pred.links)
    queued = any(link.queue_us for link in pred.links)
    links = _table("link", "messages/s", "Mbit/s", *(("emulated delay ms", "lost %") if emulated else ()),
                   *(("queue ms, most",) if queued else ()))
    for link in pred.links:
        rate = _known(None if link.bytes_per_s is None else 8 * link.bytes_per_s / 1e6, ".3g")
        if link.bytes_per_s is None and link.over:  # its known part alone is too much
            rate = f"at least {8 * link.known_bytes_per_s / 1e6:.3g}"
        rate += f" of {link.bandwidth_mbps:g}" if link.bandwidth_mbps else ""
        least, mean, most = link.delay_us
        delay = f"{mean / 1000:g}" + (f" ({least / 1000:g}..{most / 1000:g})" if least != most else "")
        links.add_row(link.name + (" (local)" if link.local else ""), _known(link.messages_per_s, ".0f"),
                      f"[red]{rate}[/]" if link.over else rate,
                      *((delay, f"{link.lost_pct:.3g}") if emulated else ()),
                      *((f"{link.queue_us / 1000:.3g}",) if queued else ()))
    console.print(links)


def print_beside(console: Console, old: Prediction, new: Prediction, traffic: tuple[float, float]) -> None:
    """Two predictions of one system's processes (an allocation): per DPU, per chain, traffic
    between DPUs (bytes/s, given: it depends on where readers are)."""
    table = _table("DPU", "load % before", "after", "processes after")
    for d in new.dpus:
        before = next((f"{o.load_pct:.1f}" for o in old.dpus if o.id == d.id), "-")
        names = ", ".join(p.name for p in new.processes if p.dpu == d.id)
        after = f"{d.load_pct:.1f}" if d.schedulable else f"[red]{d.load_pct:.1f}[/]"
        table.add_row(str(d.id), before, after, names or "-")
    console.print(table)
    worst = _table("", "before", "after")
    worst.add_row("worst DPU load %", f"{old.worst_load_pct:.1f}", f"{new.worst_load_pct:.1f}")
    worst.add_row("every DPU schedulable", *("yes" if p.schedulable else "no" for p in (old, new)))
    for a, b in zip(old.chains, new.chains, strict=True):
        worst.add_row(f"chain {a.name}: worst ms", _ms(a.worst_us), _ms(b.worst_us))
    worst.add_row("traffic between DPUs kB/s, at most", f"{traffic[0] / 1000:.3g}",
                  f"{traffic[1] / 1000:.3g}")
    console.print(worst)
