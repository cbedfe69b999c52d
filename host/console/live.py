"""The live view the page shows: what `skel watch` hears and tallies (cli/watch.py's Heard,
incremental tables: each refresh costs the new records only, so a long run stays bounded),
in a thread of its own, as one JSON snapshot at a time."""

from __future__ import annotations

import os
import threading
import time
from typing import Any

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
        self._thread = threading.Thread(target=self._loop, name="skel-console-live", daemon=True)
        self._thread.start()

    def _loop(self) -> None:
        try:
            lc = _subscribe(self.url, self.heard)
        except (RuntimeError, ValueError, OSError) as e:
            self.error = f"cannot hear {self.url}: {e}"
            return
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
        if self.error:
            view["error"] = self.error
        return view

    def stop(self) -> None:
        self._stopped.set()
        self._thread.join(2 * REFRESH_S)


def live_view(heard: Heard, url: str) -> dict[str, Any]:
    """What the page shows of what `heard` heard: the DPUs' states, the followed run's live
    tables (`skel watch`'s), and its faults as found, each with what the graph marks (the process,
    the DPU, a jam's chain from its head to the root cause)."""
    tables = heard.tables
    with heard.listener.lock:
        found = list(zip(heard.faults, heard.listener.found, strict=False))[-FAULTS_SHOWN:]
    states = {d: STATE_NAMES.get(s.state, str(s.state)) for d, s in heard.latest.items()}
    out: dict[str, Any] = {"url": url, "run_id": heard.run_id,
                           "states": {str(d): s for d, s in sorted(states.items())},
                           "faults": [{"at_s": round(at, 1), "text": text, "kind": f.kind, "fatal": f.fatal,
                                       "process": f.process, "dpu": f.dpu, "chain": f.chain}
                                      for (at, text), f in found]}
    if tables is None:
        return out
    out.update({
        "system": tables.system.name, "generation": tables.generation,
        "elapsed_s": round(tables.elapsed_ms / 1000, 1), "lost_batches": heard.lost_batches,
        "records": heard.store.n_records if heard.store else 0,
        "dpus": [_dpu_row(d) for d in tables.dpus],
        "processes": [{"name": p.name, "dpu": p.dpu, "cycles": p.cycles, "overruns": p.overruns,
                       "latency_p50_us": _pct(p.latency_us.p50), "latency_p99_us": _pct(p.latency_us.p99),
                       "latency_max_us": _pct(p.latency_us.max), "late": p.late, "too_late": p.too_late}
                      for p in tables.processes]})  # fmt: skip
    return out


def _dpu_row(d: Any) -> dict[str, Any]:
    shares = d.shares_pct  # (compute, communicate, wait, overhead): skel watch's bar
    return {"id": d.id, **{f"{name}_pct": _pct(s) for name, s in zip(SHARES, shares, strict=True)},
            "overruns": d.overruns, "records": d.records}


def _pct(value: float | None) -> float | None:
    return None if value is None else round(float(value), 1)
