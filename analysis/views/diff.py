"""`skel diff RUN_A RUN_B [--json]`: two runs' tables side by side with deltas (B - A).

Matched by DPU id, process name, buffer name and chain name; an item only in B is
"added", only in A "removed". Each run is compared on its report's top level: the
whole run, or its last generation window when the config changed mid-run. The
JSON and the tables carry the same content, so an engineer sees what a
reallocation or a faster link changed.
"""

from __future__ import annotations

import json
import os
import sys
from collections.abc import Callable, Sequence
from typing import Any, TypeVar

from ..errors import EXIT_BAD_INPUT, EXIT_OK
from ..measure.report import RunReport
from ..measure.run import RunAnalysis, load_run
from ..read.messages import LogError

T = TypeVar("T")

DPU_MEASURES = ("compute_pct", "communicate_pct", "wait_pct", "overhead_pct", "measured_cycle_ms")
PROCESS_MEASURES = ("overruns", "latency_p99_us", "response_p99_us", "compute_mean_us")
BUFFER_MEASURES = ("latency_p99_us", "dropped", "lost")
CHAIN_MEASURES = ("latency_p50_us", "latency_p99_us", "samples")


def pair(a: float | None, b: float | None) -> dict[str, float | None]:
    """{a, b, delta = b - a} (delta None when either side has no value)."""
    delta = None if a is None or b is None else b - a
    return {"a": a, "b": b, "delta": delta}


def _dpu(d: Any) -> dict[str, Any]:
    return {k: getattr(d, k) for k in DPU_MEASURES} | {"processes": d.processes}


def _process(p: Any) -> dict[str, Any]:
    return {
        "overruns": p.overruns,
        "latency_p99_us": p.latency_us.p99,
        "response_p99_us": p.response_us.p99,
        "compute_mean_us": p.compute_mean_us,
        "dpu": p.dpu,
    }


def _buffer(b: Any) -> dict[str, Any]:
    return {"latency_p99_us": b.latency_us.p99, "dropped": b.dropped, "lost": b.lost, "writer": b.writer}


def _chain(c: Any) -> dict[str, Any]:
    return {"latency_p50_us": c.latency_us.p50, "latency_p99_us": c.latency_us.p99, "samples": c.samples}


def _match(
    key: str,
    a: Sequence[T],
    b: Sequence[T],
    ident: Callable[[T], Any],
    values: Callable[[T], dict[str, Any]],
    measures: Sequence[str],
    extra: Sequence[str] = (),
) -> list[dict[str, Any]]:
    """One row per item of A (in A's order), then the items only in B."""
    by_a = {ident(x): values(x) for x in a}
    by_b = {ident(x): values(x) for x in b}
    order = list(by_a) + [k for k in by_b if k not in by_a]
    rows = []
    for k in order:
        va, vb = by_a.get(k), by_b.get(k)
        status = "both" if va is not None and vb is not None else ("removed" if vb is None else "added")
        row: dict[str, Any] = {key: k, "status": status}
        for m in measures:
            row[m] = pair(None if va is None else va[m], None if vb is None else vb[m])
        for m in extra:
            row[m] = {"a": None if va is None else va[m], "b": None if vb is None else vb[m]}
        rows.append(row)
    return rows


def _side(path: str | os.PathLike[str], r: RunReport) -> dict[str, Any]:
    return {"path": str(path), "system": r.system, "run_id": r.run_id, "generation": r.generation}


def diff_reports(
    a: RunReport, b: RunReport, path_a: str | os.PathLike[str] = "A", path_b: str | os.PathLike[str] = "B"
) -> dict[str, Any]:
    """The comparison of two reports, as JSON-ready data."""
    return {
        "a": _side(path_a, a),
        "b": _side(path_b, b),
        "dpus": _match("id", a.dpus, b.dpus, lambda d: d.id, _dpu, DPU_MEASURES, ("processes",)),
        "processes": _match(
            "name", a.processes, b.processes, lambda p: p.name, _process, PROCESS_MEASURES, ("dpu",)
        ),
        "buffers": _match(
            "buffer", a.buffers, b.buffers, lambda x: x.buffer, _buffer, BUFFER_MEASURES, ("writer",)
        ),
        "chains": _match("name", a.chains, b.chains, lambda c: c.name, _chain, CHAIN_MEASURES),
    }


def diff_command(a: str | os.PathLike[str], b: str | os.PathLike[str], as_json: bool,
                 key: bytes | None = None) -> int:
    """`skel diff RUN_A RUN_B`: 0, or 2 (one line) when either log cannot be analysed."""
    runs = []
    for path in (a, b):
        try:
            runs.append(load_run(path, key=key))
        except LogError as e:
            print(f"{path}: {e}", file=sys.stderr)
            return EXIT_BAD_INPUT
    diff = compare(*runs)
    if as_json:
        json.dump(diff, sys.stdout, indent=2)
        sys.stdout.write("\n")
    else:
        print_diff(diff)
    return EXIT_OK


def compare(a: RunAnalysis, b: RunAnalysis) -> dict[str, Any]:
    """Two runs side by side with deltas: what `skel diff` prints, as `--json` writes it."""
    return diff_reports(a.report, b.report, a.path, b.path)


LABELS = {
    "compute_pct": "% compute", "communicate_pct": "% communicate", "wait_pct": "% wait",
    "overhead_pct": "% overhead", "measured_cycle_ms": "measured cycle ms", "overruns": "overruns",
    "latency_p99_us": "latency p99 µs", "response_p99_us": "response p99 µs",
    "compute_mean_us": "compute mean µs", "dropped": "dropped", "lost": "lost",
    "latency_p50_us": "latency p50 µs", "samples": "samples",
}  # fmt: skip


def _fmt(value: Any, signed: bool = False) -> str:
    if value is None:
        return "-"
    if isinstance(value, float):
        text = f"{value:+.{_digits(value)}f}" if signed else f"{value:.{_digits(value)}f}"
        return "0" if signed and float(text) == 0 else text
    if isinstance(value, int) and not isinstance(value, bool):
        return f"{value:+d}" if signed and value else str(value)
    return str(value)


def _digits(value: float) -> int:
    return 0 if abs(value) >= 1000 else 2


def _shown_delta(cell: dict[str, Any]) -> str:
    """The Δ of the A and B the table shows: from the exact values, 90.316 and 90.314 would
    read 90.32, 90.31 and Δ 0. The JSON keeps the exact delta."""
    a, b = cell["a"], cell["b"]
    if isinstance(a, float) or isinstance(b, float):
        if a is None or b is None:
            return _fmt(None)
        delta = float(_fmt(float(b))) - float(_fmt(float(a)))
        return _fmt(round(delta, max(_digits(float(a)), _digits(float(b)))), signed=True)
    return _fmt(cell["delta"], signed=True)


def _item(row: dict[str, Any], key: str, extra: Sequence[str]) -> list[str]:
    """The item's name, whether it is added or removed, and what moved (e.g. its DPU):
    one line each, shown down the item column of the item's rows."""
    lines = [str(row[key]) if row["status"] == "both" else f"{row[key]} ({row['status']})"]
    for m in extra:
        a, b = row[m]["a"], row[m]["b"]
        if isinstance(a, list) or isinstance(b, list):
            a, b = ", ".join(a or []), ", ".join(b or [])
        if row["status"] == "both" and a != b:
            lines.append(f"{m} {a} -> {b}")
    return lines


def diff_rows(
    rows: list[dict[str, Any]], key: str, measures: Sequence[str], extra: Sequence[str] = ()
) -> list[list[str]]:
    """One table row per (item, measure): item, measure, A, B, delta."""
    out = []
    for row in rows:
        item = _item(row, key, extra)
        if len(item) > len(measures):
            item = [*item[: len(measures) - 1], "; ".join(item[len(measures) - 1 :])]
        item += [""] * (len(measures) - len(item))
        for i, m in enumerate(measures):
            cell = row[m]
            out.append(
                [
                    item[i],
                    LABELS.get(m, m),
                    _fmt(cell["a"]),
                    _fmt(cell["b"]),
                    _shown_delta(cell),
                ]
            )
    return out


def print_diff(diff: dict[str, Any], console: Any = None) -> None:
    from rich.table import Table

    from .console import output_console  # rich is only needed for tables

    console = console or output_console()
    for side in ("a", "b"):
        s = diff[side]
        head = f"{side.upper()}: {s['path']} ({s['system']}, run {s['run_id']}, generation {s['generation']})"
        console.print(head, markup=False, highlight=False)
    sections = [
        ("per DPU", "dpus", "id", DPU_MEASURES, ("processes",)),
        ("per process", "processes", "name", PROCESS_MEASURES, ("dpu",)),
        ("per buffer", "buffers", "buffer", BUFFER_MEASURES, ("writer",)),
        ("per chain", "chains", "name", CHAIN_MEASURES, ()),
    ]
    for title, section, key, measures, extra in sections:
        if not diff[section]:
            continue
        table = Table(title=f"{title}: B - A")
        for name, justify in (
            ("item", "left"),
            ("measure", "left"),
            ("A", "right"),
            ("B", "right"),
            ("Δ", "right"),
        ):
            table.add_column(name, justify=justify, no_wrap=justify == "right")  # type: ignore[arg-type]
        for i, r in enumerate(diff_rows(diff[section], key, measures, extra)):
            table.add_row(*r, end_section=i % len(measures) == len(measures) - 1)
        console.print(table)
