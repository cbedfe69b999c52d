"""Push, Run and Compare from the page: `skel push`, `skel run` and `skel diff` themselves,
run as commands (the same two-phase commit, the same run and record, the same deltas), one
at a time, their output shown as they print it. The runs started here are the session's
notebook."""

from __future__ import annotations

import json
import subprocess
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from skeleton.analysis.errors import SkelError

OUTPUT_LINES = 400  # the last lines of a job's output the page is given
STOP_WAIT_S = 30.0  # a run told to stop writes its report first
KEPT_JOBS = 20  # the commands remembered (the runs are all kept, in the notebook)


@dataclass
class Job:
    kind: str  # push | run | diff | report
    argv: list[str]
    out: Path | None = None  # the run's directory (a run's, or a report's)
    edits: list[str] = field(default_factory=list)
    lines: list[str] = field(default_factory=list)
    returncode: int | None = None
    started: float = field(default_factory=time.time)

    def to_json(self) -> dict[str, Any]:
        return {"kind": self.kind, "command": " ".join(["skel", *self.argv]),
                "running": self.returncode is None,
                "returncode": self.returncode, "output": self.lines[-OUTPUT_LINES:],
                "out": str(self.out) if self.out else None}


class Busy(SkelError):
    """A command is under way: one at a time, as at a terminal, but for a push into the run the
    page started (the page gets 409)."""


class Jobs:
    def __init__(self, runs_dir: Path) -> None:
        self.runs_dir = runs_dir
        self.started: list[Job] = []  # every command the page started, oldest first
        self.runs: list[Job] = []  # the session's runs, oldest first
        self._lock = threading.Lock()
        self._procs: list[subprocess.Popen[str]] = []
        self._followers: list[threading.Thread] = []
        self._batch: Job | None = None  # the first of the commands shown

    def running(self) -> list[Job]:
        return [job for job in self.started if job.returncode is None]

    def shown(self) -> list[Job]:
        """What the page shows: the commands started since the last one started with nothing
        running (a run and the pushes into it, or a single command), running or ended."""
        return self.started[self.started.index(self._batch):] if self._batch in self.started else []

    def start(self, job: Job) -> Job:
        """Start `job`'s command, unless one is running: a push may go into the page's run
        (live reconfiguration), nothing else goes beside another command."""
        with self._lock:
            busy = self.running()
            if busy and not (job.kind == "push" and all(j.kind == "run" for j in busy)):
                raise Busy(f"`{busy[0].to_json()['command']}` is still running")
            if not busy:
                self._batch = job
            self.started.append(job)
            del self.started[:-KEPT_JOBS]
            if job.kind == "run":
                self.runs.append(job)
            proc = subprocess.Popen([sys.executable, "-m", "skeleton.host.cli", *job.argv],
                                    stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                    stderr=subprocess.STDOUT, text=True, errors="replace")
            self._procs = [p for p in self._procs if p.poll() is None] + [proc]
        follower = threading.Thread(target=self._follow, args=(job, proc),
                                    name=f"skel-console-{job.kind}", daemon=True)
        follower.start()
        with self._lock:
            self._followers = [t for t in self._followers if t.is_alive()] + [follower]
        return job

    @staticmethod
    def _follow(job: Job, proc: subprocess.Popen[str]) -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            job.lines.append(line.rstrip("\n"))
            del job.lines[:-OUTPUT_LINES]
        job.returncode = proc.wait()

    def stop(self) -> None:
        """The console is stopping: a job under way is ended as Ctrl-C ends it at a terminal
        (`skel run` stops the run, writes its report, stops the DPUs it spawned)."""
        for proc in self._procs:
            if proc.poll() is None:
                proc.terminate()
        for proc in self._procs:
            try:
                proc.wait(STOP_WAIT_S)
            except subprocess.TimeoutExpired:
                proc.kill()
        # a job ends when its follower has read the last line and set the return code, not when
        # its process exits: the page asked right after the stop must see it ended
        for follower in self._followers:
            follower.join(STOP_WAIT_S)

    def run_dir(self, system: str) -> Path:
        return self.runs_dir / f"{system}-{time.strftime('%Y%m%d-%H%M%S')}-{len(self.runs) + 1}"

    def recorded(self) -> list[Path]:
        """The runs recorded in the runs folder before this session (each with its report.json)."""
        session = {job.out for job in self.runs}
        if not self.runs_dir.is_dir():
            return []
        return sorted(p for p in self.runs_dir.iterdir()
                      if p not in session and (p / "report.json").is_file())

    def notebook(self) -> list[dict[str, Any]]:
        """The runs recorded before, then the session's: for each its edits (the session's), its
        verdict and per-DPU figures (report.json)."""
        earlier = [{"kind": "run", "command": None, "running": False, "returncode": None, "out": str(p),
                    "edits": [], "started": time.strftime("%m-%d %H:%M", time.localtime(p.stat().st_mtime)),
                    **_figures(p)} for p in self.recorded()]
        return earlier + [{**job.to_json(), "edits": job.edits,
                           "started": time.strftime("%H:%M:%S", time.localtime(job.started)),
                           **_figures(job.out)} for job in self.runs if job.out is not None]

    def run_of(self, out: str) -> Path | None:
        """The run directory `out` names, when it is one of the notebook's (none other is read)."""
        return next((p for p in [*self.recorded(), *(job.out for job in self.runs if job.out is not None)]
                     if str(p) == out), None)


def _figures(out: Path | None) -> dict[str, Any]:
    path = out / "report.json" if out else None
    if path is None or not path.is_file():
        return {"verdict": None, "dpus": []}
    try:
        report = json.loads(path.read_text())
    except (OSError, ValueError) as e:
        return {"verdict": f"report.json unreadable: {e}", "dpus": []}
    fatal = report.get("fatal")
    faults = len(report.get("faults", []))
    verdict = (f"{report.get('system')}, run {report.get('run_id')}: "
               + ("FATAL FLAW (a lockout, a jam)" if fatal else "no fatal flaw") + f", {faults} fault(s)")
    keys = ("id", "compute_pct", "communicate_pct", "wait_pct", "measured_cycle_ms", "overruns")
    dpus = [{k: d.get(k) for k in keys} for d in report.get("dpus", [])]
    return {"verdict": verdict, "fatal": fatal, "dpus": dpus}
