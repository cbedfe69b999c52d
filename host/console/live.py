"""The live view the page shows: what `skel watch` hears and tallies (cli/watch.py's Heard,
incremental tables: each refresh costs the new records only, so a long run stays bounded),
in a thread of its own, as one JSON snapshot at a time."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

from skeleton.analysis.measure.faults import Fault

from ..cli.watch import REFRESH_S, Heard, _FaultFinder, _pump, _subscribe
from ..live import spawn
from ..live.listener import STATE_NAMES

FAULTS_SHOWN = 20  # the newest faults the page lists
SHARES = ("compute", "communicate", "wait", "overhead")


class LiveView:
    """Listens on a control URL's record URL until stop(); snapshot() is the latest view."""

    def __init__(self, url: str, key: bytes | None) -> None:
        self.url = url
        self.heard = Heard(keep_events=False, key=key)
        self.error: str | None = None
        self._lock = threading.Lock()
        self._snapshot: dict[str, Any] = {"url": url, "run_id": None}
        self._stopped = threading.Event()
        self._listening = threading.Event()  # subscribed: from now on nothing sent is missed
        self._thread = threading.Thread(target=self._loop, name="skel-console-live", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        try:
            lc = _subscribe(self.url, self.heard)
        except (RuntimeError, ValueError, OSError) as e:
            self.error = f"cannot hear {self.url}: {e}"
            return
        self._listening.set()
        allowed = os.sched_getaffinity(0)
        finder = _FaultFinder(self.heard)
        try:
            while not self._stopped.is_set():
                _pump(lc, time.monotonic() + REFRESH_S)
                self.heard.refresh()
                spawn.keep_off(self.heard.pinned_here(), allowed, spawn.own_threads())
                finder.check()
                view = live_view(self.heard, self.url)
                with self._lock:
                    self._snapshot = view
        except Exception as e:  # said on the page: the console serves on without a live view
            self.error = f"live view stopped: {e}"
        finally:
            finder.stop()

    def snapshot(self) -> dict[str, Any]:
        with self._lock:
            view = dict(self._snapshot)
        view["listening"] = self._listening.is_set()
        if self.error:
            view["error"] = self.error
        return view

    def stop(self) -> None:
        self._stopped.set()
        self._thread.join(2 * REFRESH_S)


def live_view(heard: Heard, url: str) -> dict[str, Any]:
    """What the page shows of what `heard` heard: the DPUs' states, the followed run's live
    tables (`skel watch`'s) and how far it has come, and its faults as found, each with what the
    graph marks (the process, the DPU, the chain from it back to the root cause: _chain)."""
    tables = heard.tables
    with heard.listener.lock:
        found = list(zip(heard.faults, heard.listener.found, strict=False))[-FAULTS_SHOWN:]
    states = {d: STATE_NAMES.get(s.state, str(s.state)) for d, s in heard.latest.items()}
    out: dict[str, Any] = {"url": url, "run_id": heard.run_id,
                           "states": {str(d): s for d, s in sorted(states.items())},
                           "faults": [{"at_s": round(at, 1), "text": text, "kind": f.kind, "fatal": f.fatal,
                                       "process": f.process, "dpu": f.dpu, "chain": _chain(f)}
                                      for (at, text), f in found]}
    if tables is None:
        return out
    out["progress"] = _progress(heard, tables.system.critical_period_us)
    out.update({
        "system": tables.system.name, "generation": tables.generation,
        "elapsed_s": round(tables.elapsed_ms / 1000, 1), "lost_batches": heard.lost_batches,
        "records": heard.store.n_records if heard.store else 0,
        "unsearched": heard.store.unread if heard.store else 0,
        "dpus": [_dpu_row(d) for d in tables.dpus],
        "processes": [{"name": p.name, "dpu": p.dpu, "cycles": p.cycles, "overruns": p.overruns,
                       "latency_p50_us": _pct(p.latency_us.p50), "latency_p99_us": _pct(p.latency_us.p99),
                       "latency_max_us": _pct(p.latency_us.max), "late": p.late, "too_late": p.too_late}
                      for p in tables.processes]})  # fmt: skip
    return out


def _chain(fault: Fault) -> list[str]:
    """What the graph draws of a fault, from the process it struck back to the root cause: a
    jam's chain; a lockout's process and the writer it waits on (a lockout whose writer is locked
    out too is a jam's link, and the jam has that chain); else the process alone."""
    if fault.chain:
        return list(fault.chain)
    if fault.kind == "lockout" and fault.process and fault.writer:
        return [fault.process, fault.writer]
    return [fault.process] if fault.process else []


def _progress(heard: Heard, critical_period_us: int) -> dict[str, Any] | None:
    """How far the run has come, by its START and its DPUs' clocks (Listener.progress), in
    seconds and in cycles of its critical period as `run.cycles` counts them (warm-up included)."""
    found = heard.listener.progress()
    if found is None:
        return None
    elapsed_s, planned_s = found
    cycle_s = critical_period_us / 1e6
    return {"elapsed_s": round(elapsed_s, 1), "planned_s": planned_s,
            "cycle": int(elapsed_s / cycle_s + 1e-9),
            "cycles": None if planned_s is None else round(planned_s / cycle_s)}


def _dpu_row(d: Any) -> dict[str, Any]:
    shares = d.shares_pct  # (compute, communicate, wait, overhead): skel watch's bar
    return {"id": d.id, **{f"{name}_pct": _pct(s) for name, s in zip(SHARES, shares, strict=True)},
            "overruns": d.overruns, "records": d.records}


def _pct(value: float | None) -> float | None:
    return None if value is None else round(float(value), 1)
