"""report.html: the run's tables and plots in one self-contained file (images as
base64 data URIs, no external file, script or style sheet), to mail or archive."""

from __future__ import annotations

import base64
import html
import io
from pathlib import Path

from rich.console import Console

from ..measure.run import RunAnalysis
from .plots import PlotSet
from .tables import print_report

_STYLE = """
body { font-family: system-ui, sans-serif; margin: 2em auto; max-width: 1200px; color: #222; }
h1 { font-size: 1.5em; } h2 { font-size: 1.15em; margin-top: 2em; border-bottom: 1px solid #ddd; }
pre.tables { font-size: 12px; line-height: 1.25; overflow-x: auto; background: #fafafa; padding: 1em; }
figure { margin: 0; } img { max-width: 100%; } figcaption { color: #555; font-size: 0.9em; }
p.note { background: #fff6d5; padding: 0.5em 1em; border-left: 4px solid #e0b400; }
"""


def tables_html(data: RunAnalysis, width: int = 150) -> str:
    """The same tables `skel report` prints, as an HTML <pre> block with inline colours."""
    console = Console(file=io.StringIO(), width=width, record=True, color_system="truecolor")
    print_report(data.report, console=console)
    return console.export_html(inline_styles=True, code_format='<pre class="tables">{code}</pre>')


def _image(path: Path) -> str:
    return "data:image/png;base64," + base64.b64encode(path.read_bytes()).decode("ascii")


def write_html(data: RunAnalysis, made: PlotSet, out_dir: Path, source: str) -> Path:
    rep = data.report
    esc = html.escape
    title = f"{rep.system}: run {rep.run_id}"
    parts = [
        "<!DOCTYPE html>",
        f'<html lang="en"><head><meta charset="utf-8"><title>{esc(title)}</title>',
        f"<style>{_STYLE}</style></head><body>",
        f"<h1>{esc(title)}, generation {rep.generation}</h1>",
        f"<p>From <code>{esc(source)}</code>; the first {rep.warmup_cycles} cycles of every process "
        f"(warm-up) are excluded. {'<b>Fatal flaw measured.</b>' if rep.fatal else ''}</p>",
        "<h2>Tables</h2>",
        tables_html(data),
    ]
    for plot in made.plots:
        parts += [
            f"<h2>{esc(plot.title)}</h2>",
            f'<figure><img src="{_image(out_dir / plot.name)}" alt="{esc(plot.title)}">',
            f"<figcaption>{esc(plot.caption)} ({esc(plot.name)})</figcaption></figure>",
        ]
    parts += [f'<p class="note">{esc(note)}</p>' for note in made.notes]
    parts.append("</body></html>")
    page = out_dir / "report.html"
    page.write_text("\n".join(parts), encoding="utf-8")
    return page
