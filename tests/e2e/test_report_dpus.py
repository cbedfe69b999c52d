"""tests/unit/test_report.py's tests that start skel-dpu (it says what they check)."""

from __future__ import annotations

from pathlib import Path

import pytest
from analysis_synth import MS, batches, small_run, write_log
from conftest import short_servo_run
from unit.test_report import _events, _log, _two_generation_log

from skeleton.analysis.measure.run import IMPOSSIBLE, RunAnalysis, analyze_log, load_run
from skeleton.analysis.read import parallel
from skeleton.analysis.read.messages import open_run_log
from skelmsg.contract import TIMING_CHANNEL


def test_a_window_built_side_by_side_reports_what_one_built_alone_does(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The window's tables and fault searches run in threads on a large run
    (windows.window_part): a real run's report must not depend on it."""
    short_servo_run(tmp_path)
    monkeypatch.setattr(parallel, "WORTH_BYTES", 1 << 62)
    alone = load_run(tmp_path / "run.lcm").report.to_json()
    monkeypatch.setattr(parallel, "WORTH_BYTES", 0)
    monkeypatch.setattr(parallel, "WORKERS", 2)  # threads on a runner of one CPU too
    side_by_side = load_run(tmp_path / "run.lcm").report.to_json()
    assert sum(p["cycles"] for p in alone["processes"]) > 1000
    assert side_by_side == alone


def _by_parts(path: Path, part_records: int = 1) -> tuple[RunAnalysis, RunAnalysis]:
    """The analysis of the log at `path` with its report made whole, and made in parts of
    `part_records` (run.PART_RECORDS; 1: a DPU at a time)."""
    whole = analyze_log(open_run_log(path), part_records=None)
    parts = analyze_log(open_run_log(path), part_records=part_records)
    assert whole.held is not None
    return whole, parts


def test_a_long_run_reported_a_dpu_at_a_time_reports_what_it_does_whole(tmp_path: Path) -> None:
    """A long run's report is made a few DPUs at a time (report.run_part), each part's records
    let go before the next are read, what crosses DPUs (buffers, chains, lockouts and jams,
    a host's stalls, delivery) found once all parts are in: it must say what the report of
    every record at once says, in a real SERVO run (four DPUs, chains across three of them)
    and in runs with lockouts and a jam, a lost batch, a live switch and a stray batch."""
    short_servo_run(tmp_path)
    whole, parts = _by_parts(tmp_path / "run.lcm")
    assert parts.held is None  # each part's records were let go
    assert parts.report.to_json() == whole.report.to_json()
    assert sum(p.cycles for p in whole.report.processes) > 1000 and whole.report.chains[0].samples > 100
    # The views that need every record read them again.
    assert whole.held is not None and len(parts.recorded.records) == len(whole.held.records)
    assert parts.timing.to_pandas().equals(whole.timing.to_pandas())
    # Parts of more than one DPU: DPU 1 alone, then 2, then 3 and 4 (DPU 4 runs the fewest cycles).
    halves = _by_parts(tmp_path / "run.lcm", len(whole.held.records) // 2)[1]
    assert halves.report.to_json() == whole.report.to_json()
    dpu1, dpu2 = small_run()
    b8 = next(r for r in dpu1 if r.process == 1 and r.cycle == 8)
    b8.stall_ns = 10 * MS
    logs = [_log(tmp_path / "jam.lcm", lockouts=True, drop_batch=1),
            _two_generation_log(tmp_path / "switch.lcm", (dpu1, dpu2))]
    stray = batches(1, dpu1[:2], 2, generation=2**63 - 1, first_seq=900)
    stray_log = write_log(tmp_path / "s.lcm", [(TIMING_CHANNEL, t) for t in stray])
    (tmp_path / "stray.lcm").write_bytes(logs[0].read_bytes() + stray_log.read_bytes())
    flipped = next(r for r in dpu2 if r.cycle == 2)
    flipped.start_ns ^= 1 << 60  # impossible: left out, by the same bounds in every part
    logs.append(write_log(tmp_path / "flipped.lcm", _events(dpu1, dpu2)))
    # DPU 2 starting every cycle 20 min late in a log of 0.1 s: impossible by the run's usual
    # sizes, which its own, alone in its part, would not have said.
    late1, late2 = small_run()
    for r in late2:
        r.start_ns += 20 * 60 * 10**9
    logs.append(write_log(tmp_path / "lagging.lcm", _events(late1, late2)))
    analyses = {path.name: _by_parts(path) for path in [*logs, tmp_path / "stray.lcm"]}
    for name, (whole, parts) in analyses.items():
        assert parts.report.to_json() == whole.report.to_json(), name
    assert analyses["flipped.lcm"][1].report.integrity.malformed[IMPOSSIBLE] == 1
    assert analyses["lagging.lcm"][1].report.integrity.malformed[IMPOSSIBLE] == len(late2)
    # Process A's cycles in the batches of a DPU 9 no config names: A's row holds them, so the
    # run is read as one part.
    adrift = write_log(tmp_path / "adrift.lcm", _events(dpu1, dpu2) + [
        (TIMING_CHANNEL, t) for t in batches(9, [r for r in dpu1 if r.process == 0][:3], 3)])
    whole, parts = _by_parts(adrift)
    assert parts.held is not None and parts.report.to_json() == whole.report.to_json()
    kinds = {f.kind for f in analyses["jam.lcm"][1].report.faults}
    assert {"lockout", "jam"} <= kinds, kinds
