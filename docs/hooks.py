"""MkDocs hook: the reference pages generated from the code that defines them, at build time.

A page under docs/ marks where generated text goes with a line `<!-- generated: NAME -->`;
NAME is a key of GENERATORS. Nothing generated is committed, so the reference cannot drift
from the schema, the argument parser or the report's columns. Every import of the project is
in `_sources()`, the one place to update when a module moves.

The hook also adds to the site what lives outside docs/: bench/README.md (the benchmark
figures, night by night) and examples/report/*.png (the example plots).
"""

from __future__ import annotations

import argparse
import dataclasses
import inspect
import json
import os
import re
import subprocess
import sys
import tempfile
import types
import typing
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parent.parent
MARKER = re.compile(r"^<!-- generated: ([a-z-]+) -->$", re.MULTILINE)
# Files outside docs/ the site carries: repository path -> path in the site.
OUTSIDE = {"bench/README.md": "explanation/benchmark-figures.md"} | {
    f"examples/report/{p.name}": f"img/{p.name}" for p in sorted((REPO / "examples/report").glob("*.png"))}


def _sources() -> types.SimpleNamespace:
    """Every project module the reference is generated from (update here when one moves)."""
    from skeleton.analysis import errors
    from skeleton.analysis.measure import columns, report
    from skeleton.host.cli import build_parser
    from skeleton.host.sysfile import schema
    from skeleton.host.sysfile.system import load
    from skeleton.host.theory import busfit
    from skeleton.host.theory.predict import predict
    return types.SimpleNamespace(system_spec=schema.SystemSpec, build_parser=build_parser,
                                 columns=columns, run_report=report.RunReport, exitcodes=errors,
                                 load_system=load, predict=predict, busfit=busfit)


def _cell(text: str) -> str:
    return " ".join(text.split()).replace("|", "\\|")


# --- the system file: the pydantic schema ------------------------------------------------------

def _constraints(annotation: Any) -> list[str]:
    """What the validators in an annotation allow, in their own words (their docstrings)."""
    found: list[str] = []
    for arg in typing.get_args(annotation):
        found += _constraints(arg)
    for meta in getattr(annotation, "__metadata__", ()):
        doc = getattr(getattr(meta, "func", None), "__doc__", None)
        if doc:
            found.append(doc.strip())
    return found


def _models(annotation: Any) -> Iterator[type]:
    from pydantic import BaseModel
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        yield annotation
    for arg in typing.get_args(annotation):
        yield from _models(arg)


def _type(annotation: Any) -> str:
    """A type as a reader names it: a schema model links to its section, a report row by name."""
    from pydantic import BaseModel
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _type(args[0])
    if origin is typing.Literal:
        return " \\| ".join(f"`{a}`" for a in args)
    if origin in (typing.Union, types.UnionType):
        return " or ".join(_type(a) for a in args if a is not type(None)) + (
            " or null" if type(None) in args else "")
    if origin is list:
        return f"list of {_type(args[0])}"
    if origin is dict:
        return f"mapping {_type(args[0])} → {_type(args[1])}"
    if origin is tuple:
        return "list"
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return f"[{annotation.__name__}](#{annotation.__name__.lower()})"
    return getattr(annotation, "__name__", str(annotation))


def _annotation(model: type, name: str) -> Any:
    return typing.get_type_hints(model, include_extras=True)[name]


def system_file(src: types.SimpleNamespace) -> str:
    from pydantic import BaseModel
    from pydantic_core import PydanticUndefined
    out, seen, todo = [], set(), [src.system_spec]
    while todo:
        model = todo.pop(0)
        if model in seen:
            continue
        seen.add(model)
        doc = inspect.cleandoc(model.__doc__ or "")
        out += [f"### {model.__name__}", ""]
        out += [doc, ""] if doc and not doc.startswith("Usage docs") else []
        out += ["| field | type | default | constraints | description |", "|---|---|---|---|---|"]
        for name, info in model.model_fields.items():
            annotation = _annotation(model, name)
            if info.default is PydanticUndefined:
                default = "required"
            elif isinstance(info.default, BaseModel):
                default = "its own defaults"
            else:
                default = f"`{info.default!r}`"
            out.append(f"| `{name}` | {_type(annotation)} | {default} | "
                       f"{_cell('; '.join(_constraints(annotation)))} | {_cell(info.description or '')} |")
            todo += [m for m in _models(annotation) if m not in seen]
        out.append("")
    return "\n".join(out)


# --- the command line: argparse ----------------------------------------------------------------

def _subparsers(parser: argparse.ArgumentParser) -> Iterator[tuple[str, str, argparse.ArgumentParser]]:
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            helps = {a.dest: a.help or "" for a in action._choices_actions}
            for name, sub in action.choices.items():
                yield name, helps.get(name, ""), sub


def _option(action: argparse.Action) -> tuple[str, str]:
    names = ", ".join(f"`{s}`" for s in action.option_strings) or f"`{action.metavar or action.dest}`"
    if action.option_strings and action.nargs != 0:
        names += f" `{action.metavar or action.dest.upper()}`"
    detail = action.help or ""
    if action.choices and not isinstance(action, argparse._SubParsersAction):
        detail += f" (one of {', '.join(map(str, action.choices))})"
    if action.default not in (None, False, [], argparse.SUPPRESS) and "default" not in detail:
        detail += f" (default {action.default})"
    return names, detail


def cli(src: types.SimpleNamespace) -> str:
    parser = src.build_parser()
    out = [parser.description or "", ""]
    for name, help_, sub in _subparsers(parser):
        out += [f"### skel {name}", "", help_, "", "```text", sub.format_usage().strip(), "```", "",
                "| argument | what it does |", "|---|---|"]
        for action in sub._actions:
            if isinstance(action, argparse._HelpAction):
                continue
            names, detail = _option(action)
            out.append(f"| {names} | {_cell(detail)} |")
        out.append("")
    return "\n".join(out)


def exit_codes(src: types.SimpleNamespace) -> str:
    """The exit codes, from analysis/errors.py: its names and the comment beside each."""
    text = Path(src.exitcodes.__file__).read_text()
    rows = re.findall(r"^(EXIT_\w+) = (\d+)[ \t]*(?:#[ \t]*(.*))?$", text, re.MULTILINE)
    return "\n".join(["| code | name | meaning |", "|---|---|---|"]
                     + [f"| {code} | `{name}` | {_cell(why)} |" for name, code, why in rows]) + "\n"


# --- report.json and the Python API's tables --------------------------------------------------

def _comments(cls: type) -> dict[str, str]:
    """The comment beside each field in the class's source: the field's description."""
    return dict(re.findall(r"^    (\w+): [^#\n]*#\s*(.*)$", inspect.getsource(cls), re.MULTILINE))


def _report_rows(cls: type, prefix: str, seen: set[type]) -> Iterator[str]:
    hints, comments = typing.get_type_hints(cls), _comments(cls)
    for f in dataclasses.fields(cls):
        hint = hints[f.name]
        yield f"| `{prefix}{f.name}` | {_cell(_type(hint))} | {_cell(comments.get(f.name, ''))} |"
        for inner in _dataclasses(hint):
            if inner not in seen:
                seen.add(inner)
                mark = "[]" if typing.get_origin(hint) is list else ""
                yield from _report_rows(inner, f"{prefix}{f.name}{mark}.", seen)


def _dataclasses(hint: Any) -> Iterator[type]:
    if dataclasses.is_dataclass(hint) and isinstance(hint, type):
        yield hint
    for arg in typing.get_args(hint):
        yield from _dataclasses(arg)


def report_json(src: types.SimpleNamespace) -> str:
    cls = src.run_report
    out = [inspect.cleandoc(cls.__doc__ or ""), "", "| field | type | note |", "|---|---|---|"]
    out += list(_report_rows(cls, "", {cls}))
    return "\n".join(out) + "\n"


def columns(src: types.SimpleNamespace) -> str:
    out: list[str] = []
    for table, cols in src.columns.COLUMNS.items():
        out += [f"### {table}", "", "| column | meaning |", "|---|---|"]
        out += [f"| `{name}` | {_cell(text)} |" for name, text in cols.items()]
        out.append("")
    children = ", ".join(f"`{child}` (the `{field}` of each row of `{parent}`)"
                         for parent, (field, child, _, _) in src.columns.CHILD_TABLES.items())
    out += ["### " + ", ".join(src.columns.REPORT_TABLES), "",
            "report.json's rows of the same names (above), nested fields joined with `_` "
            f"(`release_latency_us_p99`), histograms left out; and {children}.", ""]
    return "\n".join(out)


# --- the reference experiment: the paper's figures beside the prediction -------------------------

def servo_table(src: types.SimpleNamespace) -> str:
    """examples/servo.yaml's DPUs: the paper's Table 1 (the file's `reference:`) beside what the
    prediction says a run will measure, both from the file, so no figure is typed here."""
    system = src.load_system(REPO / "examples" / "servo.yaml")
    prediction = src.predict(system)
    paper = system.reference.dpus
    out = [f"From `examples/servo.yaml` ({system.reference.source}) and its prediction:", "",
           "| DPU | cycle ms | processes | % compute (paper) | % communicate (paper) | % compute predicted |",
           "|---|---|---|---|---|---|"]
    for dpu in prediction.dpus:
        names = ", ".join(p.name for p in system.processes_on(dpu.id))
        row = paper[dpu.id]
        out.append(f"| {dpu.id} | {dpu.minor_cycle_us / 1000:g} | {names} | {row.compute_pct:.1f} | "
                   f"{row.communicate_pct:.1f} | {dpu.compute_pct:.1f} |")
    return "\n".join(out) + "\n"


def servo_fast_check(src: types.SimpleNamespace) -> str:
    """`skel check examples/servo-2.5ms.yaml` as a user sees it: the prediction of the paper's
    jam, run when the site is built, so no figure of it is typed."""
    done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", "check", "examples/servo-2.5ms.yaml"],
                          cwd=REPO, capture_output=True, text=True, timeout=120,
                          env={**os.environ, "COLUMNS": "100"})
    if done.returncode not in (0, 1):
        raise RuntimeError(f"skel check examples/servo-2.5ms.yaml: exit {done.returncode}: {done.stderr}")
    return "```text\n$ skel check examples/servo-2.5ms.yaml\n" + done.stdout.rstrip() + "\n```\n"


def _cost(value: float, cost: Any) -> str:
    return f"`{cost.name}: {value:.4g}`"


def servo_bus_fit(src: types.SimpleNamespace) -> str:
    """examples/servo.yaml's reference fitted by every bus model of host/theory/busfit.py, then the
    chosen one's twelve cells beside the paper's: every figure computed when the site is built."""
    system = src.load_system(REPO / "examples" / "servo.yaml")
    fits = src.busfit.fits(system)
    ids = [row.dpu for row in fits[src.busfit.CHOSEN].rows]
    out = ["| model | what it charges | fitted (least squares, none negative) | "
           + " | ".join(f"Δ % comm. DPU {d}" for d in ids) + " | worst of the 12 cells | "
           "Δ % comm. left out of the fit, per DPU |",
           "|---|---|---|" + "---|" * len(ids) + "---|---|"]
    for name, f in fits.items():
        costs = ", ".join(_cost(v, c) for v, c in zip(f.values, f.model.costs, strict=True))
        out.append(f"| `{name}` | {_cell(f.model.meaning)} | {costs} | "
                   + " | ".join(f"{row.residuals[1]:+.1f}" for row in f.rows) + f" | {f.worst:.1f} | "
                   + " / ".join(f"{r:+.1f}" for r in f.left_out) + " |")
    chosen = fits[src.busfit.CHOSEN]
    out += ["", f"The chosen model, `{chosen.model.name}`:", ""]
    out += [f"- {_cost(v, c)}: {_cell(c.meaning)}"
            for v, c in zip(chosen.values, chosen.model.costs, strict=True)]
    out += ["", "| DPU | % compute paper / model (Δ) | % communicate paper / model (Δ) | "
            "% wait paper / model (Δ) | compute + communicate asked | cycle ms paper / model |",
            "|---|---|---|---|---|---|"]
    for row in chosen.rows:
        model = (row.compute_pct, row.communicate_pct, row.wait_pct)
        paper = (row.paper.compute_pct, row.paper.communicate_pct, row.paper.wait_pct)
        cells = [f"{p:.1f} / {m:.1f} ({r:+.1f})" for p, m, r in zip(paper, model, row.residuals, strict=True)]
        cycle = "-" if row.paper.cycle_ms is None else f"{row.paper.cycle_ms:.1f}"
        out.append(f"| {row.dpu} | " + " | ".join(cells)
                   + f" | {row.demand_pct:.1f} % | {cycle} / {row.cycle_ms:.1f} |")
    out += ["", f"Worst cell: {chosen.worst:.2f} points; % communicate residuals "
            f"{chosen.rms_communicate:.2f} points RMS over the {len(ids)} DPUs."]
    return "\n".join(out) + "\n"


def servo_vme_simulated(src: types.SimpleNamespace) -> str:
    """`skel simulate examples/servo-vme.yaml`, run when the site is built: the DPUs charging the
    fitted costs on virtual time, beside the paper and the fit."""
    command = ["simulate", "examples/servo-vme.yaml", "--json"]
    with tempfile.TemporaryDirectory() as tmp:
        out = ["--out", str(Path(tmp) / "run")]
        done = subprocess.run([sys.executable, "-m", "skeleton.host.cli", *command, *out],
                              cwd=REPO, capture_output=True, text=True, timeout=120)
        if done.returncode not in (0, 3):  # 3: DPU 4 falls behind, as the fit says
            raise RuntimeError(f"skel {' '.join(command)}: exit {done.returncode}: {done.stderr}")
    report = json.loads(done.stdout)
    rows = {row.dpu: row for row in src.busfit.fits(src.load_system(REPO / "examples" / "servo.yaml"))[
        src.busfit.CHOSEN].rows}
    out = ["| DPU | % compute paper / fit / simulated | % communicate paper / fit / simulated | "
           "% wait paper / fit / simulated | cycle ms paper / simulated |", "|---|---|---|---|---|"]
    for d in report["dpus"]:
        row = rows[d["id"]]
        cells = [f"{getattr(row.paper, c):.1f} / {getattr(row, c):.1f} / {d[c]:.1f}"
                 for c in ("compute_pct", "communicate_pct", "wait_pct")]
        cycle = "-" if row.paper.cycle_ms is None else f"{row.paper.cycle_ms:.1f}"
        out.append(f"| {d['id']} | " + " | ".join(cells) + f" | {cycle} / {d['measured_cycle_ms']:.1f} |")
    return "\n".join(out) + "\n"


def bench_summary(src: types.SimpleNamespace) -> str:
    """The summary of the `make bench` run committed to bench/results/, as it wrote it."""
    return "```text\n" + (REPO / "bench" / "results" / "summary.txt").read_text().rstrip() + "\n```\n"


GENERATORS: dict[str, Callable[[types.SimpleNamespace], str]] = {
    "system-file": system_file, "cli": cli, "exit-codes": exit_codes,
    "report-json": report_json, "columns": columns, "servo-table": servo_table,
    "bench-summary": bench_summary, "servo-fast-check": servo_fast_check,
    "servo-bus-fit": servo_bus_fit, "servo-vme-simulated": servo_vme_simulated,
}


def generate(markdown: str) -> str:
    """The page with each marker replaced by its generated text (an unknown marker is an error)."""
    src = _sources()

    def one(m: re.Match[str]) -> str:
        if m.group(1) not in GENERATORS:
            raise ValueError(f"unknown generated section {m.group(1)!r}; known: {sorted(GENERATORS)}")
        return GENERATORS[m.group(1)](src)
    return MARKER.sub(one, markdown)


# --- MkDocs events -------------------------------------------------------------------------------

def on_files(files: Any, config: Any) -> Any:
    from mkdocs.structure.files import File
    for source, dest in OUTSIDE.items():
        path = REPO / source
        if dest.endswith(".md"):
            files.append(File.generated(config, dest, content=path.read_text()))
        else:
            files.append(File.generated(config, dest, abs_src_path=str(path)))
    return files


def on_page_markdown(markdown: str, page: Any, config: Any, files: Any) -> str:
    return generate(markdown)
