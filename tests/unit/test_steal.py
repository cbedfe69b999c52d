"""tests/steal.py grants another attempt on the platform's evidence from outside the code under
test only: the kernel's steal counter and the harness's probe (tests/probe/probe.c), never what
a DPU logs of itself."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path
from types import SimpleNamespace

import pytest
import steal
from steal import PROBE_LATE_MS, STEAL_SHARE, Lateness, another_attempt, no_evidence, probe_lateness

MS = 1_000_000


def _probe_file(*late_ms: float, klass: str = "fifo") -> str:
    """A probe's file: its class, then one wake-up 10 ms after the other, each LATE_MS late."""
    wake_ups = (f"{(1_000 + 10 * i) * MS} {round(ms * MS)}\n" for i, ms in enumerate(late_ms))
    return "".join([f"{klass}\n", *wake_ups])


def test_the_probe_says_its_latest_wake_up_and_the_share_of_time_its_late_ones_lost() -> None:
    # over 2 s: 0.3 ms late is reported but below PROBE_LATE_MS, so it loses nothing
    assert probe_lateness(_probe_file(0.3, 4.0, 16.0), 2.0) == Lateness(16.0, 0.010)
    assert probe_lateness(_probe_file(0.3, PROBE_LATE_MS), 1.0) == Lateness(PROBE_LATE_MS, 0.001)
    assert probe_lateness(_probe_file(), 5.0) == Lateness(0.0, 0.0)


def test_a_probe_that_was_refused_sched_fifo_is_no_evidence() -> None:
    """Under SCHED_OTHER the DPUs themselves could have made it late."""
    assert probe_lateness(_probe_file(50.0, klass="other"), 1.0) is None
    assert probe_lateness("", 1.0) is None   # it never started


@pytest.mark.parametrize(("stolen", "probe", "again"), [
    (0.0, None, False),                                   # no witness saw anything
    (0.0, Lateness(0.0, 0.0), False),
    (STEAL_SHARE * 0.99, Lateness(0.9, 0.0), False),
    (STEAL_SHARE, None, True),                            # the hypervisor took the CPUs
    (0.0, Lateness(9.0, STEAL_SHARE), True),              # it kept the probe from running
    (0.0, Lateness(24.0, STEAL_SHARE * 0.99), False),     # one late wake-up, as the floor has: no evidence
])
def test_another_attempt_only_when_steal_or_the_probe_lost_steal_share_of_the_time(
        stolen: float, probe: Lateness | None, again: bool) -> None:
    assert another_attempt(stolen, probe) is again


@pytest.mark.parametrize(("stolen", "probe", "void"), [
    (steal.INCONCLUSIVE_SHARE, None, True),
    (0.0, Lateness(30.0, steal.INCONCLUSIVE_SHARE), True),
    (steal.INCONCLUSIVE_SHARE * 0.99, Lateness(30.0, steal.INCONCLUSIVE_SHARE * 0.99), False),
])
def test_an_attempt_says_nothing_either_way_only_past_inconclusive_share(
        stolen: float, probe: Lateness | None, void: bool) -> None:
    assert no_evidence(stolen, probe) is void


class _Seen:
    """A probe's evidence, as read after an attempt."""

    def __init__(self, lateness: Lateness | None) -> None:
        self._lateness = lateness

    def lateness(self) -> Lateness | None:
        return self._lateness


def _attempt(root: Path, stolen_ns: int, probe: Lateness | None) -> steal.Attempt:
    """An attempt of one second in which the hypervisor took STOLEN_NS and the probe saw PROBE."""
    return steal.Attempt("t::x", time.monotonic() - 1.0, steal.stolen_ns() - stolen_ns, root,
                         _Seen(probe))  # type: ignore[arg-type]


@pytest.fixture
def fresh(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(steal, "_reattempted", [])
    monkeypatch.setattr(steal, "_reattempted_tests", set())
    monkeypatch.setattr(steal, "_reattempted_on_valid", set())
    monkeypatch.setattr(steal, "_evidenced", {})
    monkeypatch.setattr(steal, "_reattempt_s", 0.0)


def test_what_a_dpu_logs_of_its_own_stalls_and_speed_buys_no_attempt(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch, fresh: None) -> None:
    root = tmp_path_factory.mktemp("attempt")
    log = root / "dpu-logs" / "dpu1.log"
    log.parent.mkdir()
    log.write_text("skel-dpu[1]: DPU 1: run 1 ended: 500 cycles, longest platform stall 50.0 ms\n"
                   "skel-dpu[1]: DPU 1: at the run's end the WORK kernel runs 97.5 % slower\n")
    monkeypatch.setattr(steal, "_current", _attempt(root, 0, Lateness(0.4, 0.0)))
    assert not steal.platform_took_the_cpus(AssertionError("late"))
    monkeypatch.setattr(steal, "_current", _attempt(root, 0, Lateness(12.0, 0.02)))
    assert steal.platform_took_the_cpus(AssertionError("late"))   # the probe's witness
    assert steal._reattempted == ["t::x: 0 ms stolen (0.0 % of the CPUs' time), the probe woke up to 12.0 ms "
                                  "late (2.0 % of the time lost), AssertionError"]
    for _ in range(steal.REATTEMPTS):   # the next attempts, each failed as the platform took the time
        monkeypatch.setattr(steal, "_current", _attempt(root, 0, Lateness(12.0, 0.02)))
        assert steal.platform_took_the_cpus(AssertionError("late"))
    # listed once per attempt made again: the last one is not
    assert len(steal._reattempted) == steal.REATTEMPTS and steal._reattempted_tests == {"t::x"}


def test_the_probe_runs_under_sched_fifo_where_permitted_and_reads_as_evidence(tmp_path: Path) -> None:
    probe = steal.Probe(tmp_path / "probe.txt")
    try:
        time.sleep(0.05)
        first = (tmp_path / "probe.txt").read_text().split("\n", 1)[0]
        assert first == "fifo" or (first == "other" and os.geteuid() != 0), first  # root may
        assert (probe.lateness() is None) == (first != "fifo")
    finally:
        probe.stop()


def test_an_attempt_whose_dpu_wrote_a_sanitizer_report_is_never_run_again(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch, fresh: None) -> None:
    # the attempt's logs outside this test's own tmp_path, which conftest judges after the test
    root = tmp_path_factory.mktemp("attempt")
    # the hypervisor took every CPU: the platform's evidence at its most
    monkeypatch.setattr(steal, "_current", _attempt(root, 10 ** 10, Lateness(500.0, 0.5)))
    log = root / "dpu-logs" / "dpu1.log"
    log.parent.mkdir()
    log.write_text("skel-dpu[1]: run 1 started\n")
    assert steal.platform_took_the_cpus(AssertionError("late"))       # the platform's, another attempt
    log.write_text("==1==ERROR: AddressSanitizer: heap-buffer-overflow on address 0x6020\n")
    assert not steal.platform_took_the_cpus(AssertionError("late"))   # ours, whatever was stolen


def _finish(monkeypatch: pytest.MonkeyPatch, evidence: Path, reattempted: int, inconclusive: int,
            voided: int = 0) -> int:
    """The session's end after REATTEMPTED tests needed another attempt on valid evidence and
    VOIDED more after failed attempts the platform voided."""
    monkeypatch.setattr(steal, "EVIDENCE_FILE", evidence)
    valid = {f"t::{i}" for i in range(reattempted)}
    monkeypatch.setattr(steal, "_reattempted_tests", valid | {f"t::v{i}" for i in range(voided)})
    monkeypatch.setattr(steal, "_reattempted_on_valid", valid)
    monkeypatch.setattr(steal, "_inconclusive", [f"t::{i}: inconclusive" for i in range(inconclusive)])
    monkeypatch.setattr(steal, "_verdict", [])
    monkeypatch.setattr(steal, "_reattempt_s", 0.0)
    session = SimpleNamespace(exitstatus=0, config=SimpleNamespace(option=SimpleNamespace(collectonly=False)))
    steal.pytest_sessionfinish(session, 0)  # type: ignore[arg-type]
    return int(session.exitstatus)


def test_a_run_says_how_many_tests_needed_another_attempt_and_fails_past_the_limit(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    evidence = tmp_path / "evidence.json"
    assert _finish(monkeypatch, evidence, steal.MAX_REATTEMPTED, 0, voided=2) == 0
    assert steal._verdict == [
        f"timing evidence: {steal.MAX_REATTEMPTED + 2} test(s) needed another attempt, "
        f"{steal.MAX_REATTEMPTED} of them after a failed attempt the platform did not void (at most "
        f"{steal.MAX_REATTEMPTED}; 2 after one it voided), 0 inconclusive (the run before: 0); "
        f"attempts again took 0 s (at most {steal.REATTEMPT_BUDGET_S:.0f})"]
    assert _finish(monkeypatch, evidence, steal.MAX_REATTEMPTED + 1, 0) == 1
    assert steal._verdict[-1].startswith(f"FAILED: more than {steal.MAX_REATTEMPTED} tests needed another")
    # attempts the platform voided say nothing either way: any number of them
    assert _finish(monkeypatch, evidence, 0, 0, voided=3 * steal.MAX_REATTEMPTED) == 0


def test_a_failed_attempt_the_platform_voided_does_not_count_towards_the_limit(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch, fresh: None) -> None:
    root = tmp_path_factory.mktemp("attempt")
    monkeypatch.setattr(steal, "_current", _attempt(root, 0, Lateness(30.0, steal.INCONCLUSIVE_SHARE)))
    assert steal.platform_took_the_cpus(AssertionError("late"))
    assert steal._reattempted_tests == {"t::x"} and steal._reattempted_on_valid == set()
    monkeypatch.setattr(steal, "_current", _attempt(root, 0, Lateness(12.0, STEAL_SHARE)))
    assert steal.platform_took_the_cpus(AssertionError("late"))
    assert steal._reattempted_on_valid == {"t::x"}


def test_no_attempt_again_once_the_sessions_attempts_again_took_their_budget(
        tmp_path_factory: pytest.TempPathFactory, monkeypatch: pytest.MonkeyPatch, fresh: None) -> None:
    root = tmp_path_factory.mktemp("attempt")
    monkeypatch.setattr(steal, "_current", _attempt(root, 10 ** 10, Lateness(500.0, 0.5)))
    monkeypatch.setattr(steal, "_reattempt_s", steal.REATTEMPT_BUDGET_S)
    assert not steal.platform_took_the_cpus(AssertionError("late"))


def test_a_test_inconclusive_in_two_runs_in_a_row_fails_the_second(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    evidence = tmp_path / "evidence.json"
    assert _finish(monkeypatch, evidence, 0, 1) == 0      # once: reported, kept in the file
    assert json.loads(evidence.read_text()) == {"inconclusive": 1, "reattempted": 0,
                                                "reattempted_on_valid_evidence": 0}
    assert _finish(monkeypatch, evidence, 0, 1) == 1      # again in the next run: a failure
    assert _finish(monkeypatch, evidence, 0, 0) == 0
    assert _finish(monkeypatch, evidence, 0, 1) == 0      # after a conclusive run: once again


def test_the_cpu_that_lost_the_most_is_the_attempts_evidence(monkeypatch: pytest.MonkeyPatch) -> None:
    """60 ms stolen in a second, all of it from one of two CPUs: 3 % of the machine's time, 6 % of
    the time of the CPU its DPUs were pinned to, which voids the attempt."""
    now = (10**12, 10**12)
    monkeypatch.setattr(steal, "stolen_per_cpu_ns", lambda: now)
    monkeypatch.setattr(steal, "_CPUS", 2)
    attempt = steal.Attempt("t::x", time.monotonic() - 1.0, steal.stolen_ns() - 60_000_000, None, None,
                            stolen_at_start_per_cpu=(now[0] - 60_000_000, now[1]))
    ms, share = attempt.stolen_share()
    assert round(ms) == 60 and 0.055 < share <= 0.06 and steal.no_evidence(share, None)
