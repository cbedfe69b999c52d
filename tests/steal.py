"""Timing tests on a shared virtual machine: a second attempt only when the platform took the CPUs.

A test marked `timing` judges how the DPUs kept time: responses against response-time analysis,
% compute against Table 1, lockouts that must not happen. On a virtual machine the hypervisor
runs other guests on our cores (the kernel counts it as steal time): every DPU of the host
stops for tens of milliseconds at once, and such a test fails on the platform, not the code.
The hypervisor also stops a vCPU without the guest counting it as steal at all (on our CI's
VMs: gaps of 1-17 ms, 1.5-2 % of the time, with 0-3 ticks of steal): only the DPUs see those,
as stalls (a gap in a computation or a wake-up later than the stall threshold, with no switch
of the thread), and each DPU's log says at the end of a run the most one cycle lost to them.

Steal comes in spells (here: seconds to tens of seconds at 10-45 % of the CPUs, between long
stretches under 2 %). So an attempt of such a test does not start in one: while more than
QUIET_SHARE of the CPUs' time was stolen over the last QUIET_WINDOW_S, it waits, at most
QUIET_WAIT_S per attempt and QUIET_BUDGET_S in the session (CI's time is bounded too).

The platform also slows a vCPU without stopping it (a neighbour on its physical core, or the
host's clock speed): every instruction takes longer, with no steal and no gap. A WORK
computation (a fixed number of iterations of a kernel) then takes longer. Each DPU measures its
kernel's speed at a run's start and end and logs how far it is from its calibration when more
than 2 % off: here one two-second run measured 97.5 % slower at its start and 10 % faster at
its end (runs of 130 us of the kernel here, 1 ms apart: p10 110-300 iterations/us, p90
310-330, p1 25-250).

Such a test fails as usual, but when the CPU time stolen during the failed attempt is at least
STEAL_SHARE of the CPUs' time, or a DPU of the attempt (a log under its tmp_path) was stalled
by the platform for STALL_MS or longer in one cycle, or its WORK kernel ran WORK_OFF_PCT or more
off its calibration at a run's start or end (what the DPU logs: a run's speed between those two
samples can be further off still; CI once: 2.1 % at the end, the median computation 5.5 %),
pytest-rerunfailures runs it again from its fixtures up, at most REATTEMPTS more times. Every
attempt asserts the same thing, so a fault of ours fails each of them; the session's summary
names every test that needed another attempt, what was stolen, how long a DPU was stalled and
how far its kernel's speed was off and moved, and how long attempts waited for a spell to pass.

A test whose every attempt failed while the hypervisor took at least INCONCLUSIVE_SHARE of the
CPUs (well above the 1-4 % of a quiet hour here), or while a DPU's kernel speed moved by
INCONCLUSIVE_MOVED_PCT points or more, has no valid evidence either way: it is reported skipped,
as inconclusive, with what was stolen and how far the speed moved in each attempt. One attempt
that failed with less of both is a failure.

None of this hides a fault of ours. An attempt whose DPUs wrote a sanitizer report is never run
again, whatever the platform did. Every run of pytest ends with one line counting the timing
tests that needed another attempt and the inconclusive ones, and fails (exit 1) when more than
MAX_REATTEMPTED tests needed another attempt, or when a test was inconclusive in this run and
in the run before it (the counts are kept in EVIDENCE_FILE, which each run leaves behind).
"""

from __future__ import annotations

import json
import os
import re
import threading
import time
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass
from pathlib import Path
from typing import NamedTuple

import pytest
from conftest import SANITIZER_ERROR

MAX_REATTEMPTED = 6   # tests of one run that may need another attempt (CI: 0-1 a run, 2026-11)
EVIDENCE_FILE = Path(__file__).resolve().parents[1] / "build" / "timing-evidence.json"
STEAL_SHARE = 0.01
STALL_MS = 1.0
REATTEMPTS = 2
INCONCLUSIVE_SHARE = 0.05
WORK_OFF_PCT = 2.0
INCONCLUSIVE_MOVED_PCT = 5.0
QUIET_SHARE = 0.02
QUIET_WINDOW_S = 3.0
QUIET_WAIT_S = 30.0
QUIET_BUDGET_S = 150.0
_TICK_NS = 1_000_000_000 // os.sysconf("SC_CLK_TCK")
_CPUS = os.cpu_count() or 1


def stolen_ns() -> int:
    """CPU time the hypervisor gave to others since boot, summed over CPUs (/proc/stat)."""
    cpu = Path("/proc/stat").read_text().split("\n", 1)[0].split()
    return int(cpu[8]) * _TICK_NS if len(cpu) > 8 else 0


class _Sampler(threading.Thread):
    """The steal counter every SAMPLE_S, so the gate knows the last seconds without waiting."""

    SAMPLE_S = 0.25

    def __init__(self) -> None:
        super().__init__(name="steal-sampler", daemon=True)
        self.samples: deque[tuple[float, int]] = deque(maxlen=int(QUIET_WINDOW_S / self.SAMPLE_S) + 2)
        self.samples.append((time.monotonic(), stolen_ns()))

    def run(self) -> None:
        while True:
            time.sleep(self.SAMPLE_S)
            self.samples.append((time.monotonic(), stolen_ns()))

    def recent_share(self) -> float:
        """Share of the CPUs' time stolen over the last QUIET_WINDOW_S (or what was sampled)."""
        now, latest = time.monotonic(), stolen_ns()
        then, before = next(((t, v) for t, v in list(self.samples) if now - t <= QUIET_WINDOW_S),
                            self.samples[-1])
        return (latest - before) / max((now - then) * 1e9 * _CPUS, 1.0)


_sampler: _Sampler | None = None
_waited_s = 0.0
_waits = 0


def wait_for_a_quiet_platform() -> None:
    """Before a timing attempt: let a spell of steal pass, within the per-attempt and session
    budgets; past them the attempt starts anyway and is judged as any other."""
    global _waited_s, _waits
    if _sampler is None:
        return
    began = time.monotonic()
    limit = min(QUIET_WAIT_S, QUIET_BUDGET_S - _waited_s)
    waited = False
    while _sampler.recent_share() > QUIET_SHARE and time.monotonic() - began < limit:
        waited = True
        time.sleep(_Sampler.SAMPLE_S)
    if waited:
        _waits += 1
        _waited_s += time.monotonic() - began


# A DPU's last line of a run (dpu/control.c).
_RUN_STALLS = re.compile(rb"run -?\d+ ended: .*, longest platform stall ([\d.]+) ms")


def sanitizer_report(root: Path) -> bool:
    """Did a DPU whose log is under ROOT write a sanitizer report?"""
    return any(SANITIZER_ERROR.search(log.read_bytes()) for log in root.rglob("dpu*.log"))


def longest_dpu_stall_ms(root: Path) -> float:
    """The longest platform stall any DPU whose log is under ROOT reported at the end of a run."""
    return max((float(m.group(1)) for log in root.rglob("dpu*.log")
                for m in _RUN_STALLS.finditer(log.read_bytes())), default=0.0)


# A DPU's WORK check at a run's start or end, logged when more than 2 % off (dpu/executive.c).
_WORK_DRIFT = re.compile(rb"run -?\d+ armed|"
                         rb"at the run's (start|end) the WORK kernel runs ([\d.]+) % (slower|faster)")


class WorkSpeed(NamedTuple):
    off: float  # the largest drift from its calibration a DPU logged at a run's start or end, in %
    moved: float  # the most a run's drift at its end differed from the one at its start, in points


def work_speed(root: Path) -> WorkSpeed:
    """How far the WORK kernel's speed was from its calibration in the runs of the DPUs whose
    logs are under ROOT (a drift the DPU did not log, within 2 %, counts as 0)."""
    runs: list[dict[bytes, float]] = []
    for log in root.rglob("dpu*.log"):
        for m in _WORK_DRIFT.finditer(log.read_bytes()):
            if m.group(1) is None:  # the next run
                runs.append({})
            elif runs:
                runs[-1][m.group(1)] = float(m.group(2)) * (1 if m.group(3) == b"slower" else -1)
    return WorkSpeed(max((abs(v) for run in runs for v in run.values()), default=0.0),
                     max((abs(run.get(b"end", 0.0) - run.get(b"start", 0.0)) for run in runs), default=0.0))


@dataclass
class Attempt:
    nodeid: str
    started_s: float
    stolen_at_start_ns: int
    root: Path | None = None  # the test's tmp_path, where its DPUs' logs go
    reported: bool = False

    def stolen_share(self) -> tuple[float, float]:
        """(ms stolen, its share of the CPUs' time) since the attempt began."""
        stolen = stolen_ns() - self.stolen_at_start_ns
        capacity = max(time.monotonic() - self.started_s, 1e-3) * 1e9 * (os.cpu_count() or 1)
        return stolen / 1e6, stolen / capacity

    def work_speed(self) -> WorkSpeed:
        return work_speed(self.root) if self.root is not None else WorkSpeed(0.0, 0.0)


_current: Attempt | None = None
_reattempted: list[str] = []
_reattempted_tests: set[str] = set()
_verdict: list[str] = []   # the session's one line on its timing evidence, and why it failed, if it did
# per test, the share of the CPUs stolen and the WORK speed moved in each failed attempt
_failed_attempts: dict[str, list[tuple[float, float]]] = {}
_inconclusive: list[str] = []


def platform_took_the_cpus(error: BaseException | None) -> bool:
    """pytest-rerunfailures' condition, asked after every attempt (tests run one at a time):
    with the error of each failed phase, with None after one that passed."""
    if _current is None:
        return False
    if _current.root is not None and sanitizer_report(_current.root):
        return False   # a fault of ours, whatever the platform did
    ms, share = _current.stolen_share()
    stall_ms = longest_dpu_stall_ms(_current.root) if _current.root is not None else 0.0
    work = _current.work_speed()
    if share < STEAL_SHARE and stall_ms < STALL_MS and work.off < WORK_OFF_PCT:
        return False
    if error is not None and not _current.reported:  # once per failed attempt
        _current.reported = True
        _reattempted_tests.add(_current.nodeid)
        _reattempted.append(f"{_current.nodeid}: {ms:.0f} ms stolen ({100 * share:.1f} % of the CPUs' "
                            f"time), a DPU stalled {stall_ms:.1f} ms in one cycle, its WORK kernel "
                            f"{work.off:.1f} % off (moved {work.moved:.1f} points), "
                            f"{type(error).__name__}")
    return True


@pytest.hookimpl(hookwrapper=True)
def pytest_runtest_makereport(item: pytest.Item, call: pytest.CallInfo[None]) -> Generator[None]:
    """The last attempt of a timing test that failed in every attempt, each while the platform
    took at least INCONCLUSIVE_SHARE of the CPUs or moved a DPU's WORK speed by
    INCONCLUSIVE_MOVED_PCT points: skipped as inconclusive."""
    outcome = yield
    report: pytest.TestReport = outcome.get_result()  # type: ignore[attr-defined]
    timing = item.get_closest_marker("timing") is not None
    if report.when != "call" or not report.failed or _current is None or not timing:
        return
    failed = _failed_attempts.setdefault(item.nodeid, [])
    failed.append((_current.stolen_share()[1], _current.work_speed().moved))
    if getattr(item, "execution_count", 1) <= REATTEMPTS or len(failed) <= REATTEMPTS:
        return
    if any(share < INCONCLUSIVE_SHARE and moved < INCONCLUSIVE_MOVED_PCT for share, moved in failed):
        return
    each = ", ".join(f"{100 * share:.1f} % stolen, {moved:.1f} points" for share, moved in failed)
    reason = (f"inconclusive: every attempt failed while the hypervisor took the CPUs or moved the "
              f"WORK kernel's speed within a run ({each}; {100 * INCONCLUSIVE_SHARE:.0f} % of the CPUs' "
              f"time or {INCONCLUSIVE_MOVED_PCT:.0f} points void a timing test's evidence)")
    _inconclusive.append(f"{item.nodeid}: {reason}")
    report.outcome = "skipped"
    report.longrepr = (str(item.path), item.location[1] or 0, f"Skipped: {reason}")


def pytest_configure(config: pytest.Config) -> None:
    global _sampler
    _sampler = _Sampler()
    _sampler.start()
    config.addinivalue_line("markers", "timing: judges the DPUs' timing; another attempt when the "
                                       "platform took the CPUs (tests/steal.py)")


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if item.get_closest_marker("timing") is not None:
            item.add_marker(pytest.mark.flaky(reruns=REATTEMPTS, condition=platform_took_the_cpus))


@pytest.fixture(autouse=True)
def _steal_watch(request: pytest.FixtureRequest) -> None:
    """Autouse, so it is set up before the fixtures that start DPUs: the attempt's steal counts
    from before anything of the test ran."""
    global _current
    root = None
    if request.node.get_closest_marker("timing") is not None:
        wait_for_a_quiet_platform()
        if "tmp_path" in request.fixturenames:
            root = request.getfixturevalue("tmp_path")
    _current = Attempt(request.node.nodeid, time.monotonic(), stolen_ns(), root)


def pytest_terminal_summary(terminalreporter: pytest.TerminalReporter) -> None:
    if _reattempted:
        terminalreporter.write_sep("-", "attempted again: the platform took the CPUs, stalled a DPU or "
                                        "changed its speed (tests/steal.py)")
        for line in _reattempted:
            terminalreporter.write_line(line)
    if _inconclusive:
        terminalreporter.write_sep("-", "inconclusive: every attempt failed while the platform took the CPUs")
        for line in _inconclusive:
            terminalreporter.write_line(line)
    if _waits:
        terminalreporter.write_line(f"tests/steal.py: {_waits} timing attempt(s) waited {_waited_s:.0f} s in "
                                    f"all for a spell of steal to pass")
    for line in _verdict:
        terminalreporter.write_line(line)


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """The one line on this run's timing evidence; exit 1 when it could hide a regression."""
    if session.config.option.collectonly:
        return   # nothing ran: the run before stays the one to compare with
    try:
        before = json.loads(EVIDENCE_FILE.read_text())["inconclusive"]
    except (OSError, ValueError, KeyError, TypeError):
        before = 0
    EVIDENCE_FILE.parent.mkdir(parents=True, exist_ok=True)
    EVIDENCE_FILE.write_text(json.dumps({"inconclusive": len(_inconclusive),
                                         "reattempted": len(_reattempted_tests)}) + "\n")
    _verdict.append(f"timing evidence: {len(_reattempted_tests)} test(s) needed another attempt (at most "
                    f"{MAX_REATTEMPTED}), {len(_inconclusive)} inconclusive (the run before: {before})")
    failed = []
    if len(_reattempted_tests) > MAX_REATTEMPTED:
        failed.append(f"more than {MAX_REATTEMPTED} tests needed another attempt")
    if _inconclusive and before:
        failed.append("tests were inconclusive in two runs in a row")
    if failed and session.exitstatus == 0:
        _verdict.append("FAILED: " + "; ".join(failed) + f" ({EVIDENCE_FILE})")
        session.exitstatus = pytest.ExitCode.TESTS_FAILED
