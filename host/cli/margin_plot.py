"""`skel margin --plots DIR`: each DPU's predicted load and each process's worst response against
the factor, the margin and what breaks there marked, a measured sweep's steps beside them."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # before pyplot: files only, never a window
import matplotlib.pyplot as plt

from ..model import System
from ..theory.margin import Margin, scaled
from ..theory.predict import predict

POINTS = 120
DPI = 110


def write_margin_plot(system: System, found: Margin, out_dir: Path,
                      measured: list[tuple[float, dict[int, float]]] = ()) -> Path:
    """One figure for `found` (the first scope's margin): two panels against the factor.
    `measured`: a sweep's steps, (factor, {DPU: measured % compute}). Returns its path."""
    top = 1.25 * (found.factor or 2.0)
    factors = [top * (i + 1) / POINTS for i in range(POINTS)]
    predictions = [predict(scaled(system, found.axis, f, found.scope)) for f in factors]
    fig, (load_ax, resp_ax) = plt.subplots(1, 2, figsize=(12, 4.5))
    for i, d in enumerate(system.dpus):
        load_ax.plot(factors, [p.dpus[i].load_pct for p in predictions], label=f"DPU {d.id}")
    for i, proc in enumerate(system.processes):
        worst = [p.processes[i].response_us for p in predictions]
        resp_ax.plot(factors, [float("nan") if w is None else w / p.processes[i].period_us
                               for w, p in zip(worst, predictions, strict=True)], label=proc.name)
    for dpu, pct in _by_dpu(measured).items():
        load_ax.plot(*zip(*pct, strict=True), "o", label=f"DPU {dpu} measured % compute")
    for ax, limit in ((load_ax, 100.0), (resp_ax, 1.0)):
        ax.axhline(limit, color="grey", linestyle=":")
        if found.factor is not None:
            ax.axvline(found.factor, color="red", linestyle="--")
        ax.set_xlabel(f"factor ({found.axis}, {found.scope.name})")
        ax.grid(alpha=0.3)
    load_ax.set_ylabel("predicted static load %")
    resp_ax.set_ylabel("predicted worst response / period")
    resp_ax.set_ylim(0, 2)
    load_ax.legend(fontsize=7)
    resp_ax.legend(fontsize=6, ncol=2)
    breaks = found.breaks[0] if found.breaks else "nothing"
    factor = "none" if found.factor is None else f"{found.factor:.4f}"
    fig.suptitle(f"{system.name}: margin {factor} ({found.axis}, {found.scope.name}); past it: {breaks}",
                 fontsize=9)
    fig.tight_layout()
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / f"margin-{found.axis}.png"
    fig.savefig(path, dpi=DPI)
    plt.close(fig)
    return path


def _by_dpu(measured: list[tuple[float, dict[int, float]]]) -> dict[int, list[tuple[float, float]]]:
    out: dict[int, list[tuple[float, float]]] = {}
    for factor, pcts in measured:
        for dpu, pct in pcts.items():
            out.setdefault(dpu, []).append((factor, pct))
    return out
