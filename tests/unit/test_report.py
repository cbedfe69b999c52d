"""report.py (analyze, JSON, report_command) and tables.py on synthetic logs."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pandas as pd
import pytest
from analysis_synth import (
    GENERATION,
    MS,
    RUN_ID,
    US,
    Rec,
    batches,
    report,
    small_config,
    small_run,
    status,
    write_log,
)
from rich.console import Console

from skeleton.analysis.measure.run import IMPOSSIBLE, load_run
from skeleton.analysis.measure.tally import RunTally
from skeleton.analysis.views import plots
from skeleton.analysis.views.parquet import write_parquet
from skeleton.analysis.views.report import report_command
from skeleton.analysis.views.tables import print_report
from skeleton.analysis.views.trace import write_trace
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL


def _log(path: Path, lockouts: bool = False, drop_batch: int | None = None) -> Path:
    dpu1, dpu2 = small_run()
    old = small_config(generation=GENERATION - 1)
    old.system = "stale"
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, old), (CONFIG_CHANNEL, small_config())]
    t1, t2 = batches(1, dpu1, 4), batches(2, dpu2, 2)
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 4, run_id=7)]  # an earlier run
    events += [(TIMING_CHANNEL, t) for t in t1 + t2 if not (t.dpu == 1 and t.batch_seq == drop_batch)]
    events += [(STATUS_CHANNEL, status(1, [(0, -1, 8), (1, 0, 8)] if lockouts else []))]
    events += [(STATUS_CHANNEL, status(2, [(2, 1, 4)] if lockouts else []))]
    events += [(STATUS_CHANNEL, b"not a status"), (CONFIG_CHANNEL, small_config())]
    events += [(REPORT_CHANNEL, report(1, len(t1))), (REPORT_CHANNEL, report(2, len(t2)))]
    return write_log(path, events)


def _render(rep: object, paper: dict | None = None) -> str:
    console = Console(file=io.StringIO(), width=140, record=True, color_system=None)
    print_report(rep, console=console, paper=paper)  # type: ignore[arg-type]
    return console.export_text()


def test_a_dpu_without_a_measured_cycle_is_said_why(tmp_path: Path) -> None:
    """Five warm-up cycles of DPU 2's 20 ms outlast its five cycles: its row is all dashes,
    and the table says why."""
    dpu1, dpu2 = small_run()
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config(warmup_cycles=5))]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 4) + batches(2, dpu2, 2)]
    rep = load_run(str(write_log(tmp_path / "run.lcm", events))).report
    assert [d.records for d in rep.dpus] == [10, 0]
    text = " ".join(_render(rep).split())
    assert ("DPU 2: no measured cycle here (its warm-up, warmup_cycles of its longest period, outlasted "
            "this window, or it ran none)") in text, text


def test_analyze_json_fields(tmp_path: Path) -> None:
    rep = load_run(str(_log(tmp_path / "run.lcm")), None).report
    out = rep.to_json()
    json.dumps(out)  # serialisable as is
    assert (out["run_id"], out["system"], out["generation"]) == (RUN_ID, "small", GENERATION)
    assert out["integrity"]["events"] > 0 and out["integrity"]["corrupt_ranges"] == []
    assert out["integrity"]["lost_batches"] == [] and out["integrity"]["malformed"] == {STATUS_CHANNEL: 1}
    d1 = out["dpus"][0]
    for key in ("id", "processes", "configured_cycle_ms", "measured_cycle_ms", "compute_pct",
                "communicate_pct", "wait_pct", "overhead_pct", "static_load_pct", "overruns"):  # fmt: skip
        assert key in d1
    assert d1["processes"] == ["A", "B"] and d1["compute_pct"] == pytest.approx(60.0)
    assert d1["compute_mode"] == "sleep"
    b = out["processes"][1]
    assert (b["id"], b["name"], b["dpu"], b["cycles"], b["overruns"]) == (1, "B", 1, 8, 0)
    assert set(b["latency_us"]) == {"p50", "p99", "max"} and b["late"] == 8 and b["too_late"] == 0
    assert b["inputs"] == [
        {"buffer": "a_out", "buffer_id": 0, "new": 6, "stale": 2, "dropped": 2, "received": 6}
    ]
    assert [f["kind"] for f in out["faults"]] == ["overrun"]
    assert out["faults"][0]["process"] == "C" and out["faults"][0]["count"] == 1
    assert out["cross_check"][0]["dpu"] == 1
    assert load_run(str(tmp_path / "run.lcm"), 7).report.run_id == 7


def test_jam_report_and_exit_code(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path = _log(tmp_path / "jam.lcm", lockouts=True)
    rep = load_run(str(path)).report
    jam = [f for f in rep.to_json()["faults"] if f["kind"] == "jam"]
    assert len(jam) == 1 and jam[0]["chain"] == ["C", "B", "A"]
    assert rep.fatal
    assert report_command(str(path), as_json=True, run_id=None) == 3
    assert json.loads(capsys.readouterr().out)["fatal"] is True
    assert report_command(str(_log(tmp_path / "ok.lcm")), as_json=True, run_id=None) == 0


def test_unreadable_files_give_one_line_and_exit_2(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    junk = tmp_path / "junk.lcm"
    junk.write_bytes(b"hello, this is not a log" * 10)
    assert report_command(str(junk), as_json=False, run_id=None) == 2
    assert capsys.readouterr().err.strip() == f"{junk}: not an LCM log (no event found)"
    missing = tmp_path / "missing.lcm"
    assert report_command(str(missing), as_json=False, run_id=None) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith(f"{missing}: ") and "\n" not in err
    assert report_command(str(_log(tmp_path / "r.lcm")), as_json=False, run_id=99) == 2
    assert "no timing records for run 99" in capsys.readouterr().err


def test_damaged_log_still_reports_and_says_so(tmp_path: Path) -> None:
    path = _log(tmp_path / "run.lcm", drop_batch=1)
    raw = path.read_bytes()
    mid = raw.index(STATUS_CHANNEL.encode()) - 28  # a header: garbage goes right before it
    path.write_bytes(raw[:mid] + b"\x00" * 100 + raw[mid:])
    rep = load_run(str(path)).report
    assert rep.integrity.corrupt_ranges == [(mid, mid + 100)]
    assert rep.integrity.lost_batches == [{"dpu": 1, "from_seq": 1, "to_seq": 1}]
    text = _render(rep)
    assert "log damaged: 1 corrupt ranges (100 bytes), 1 timing batches lost" in text
    assert "the tables use everything else" in text


def test_a_record_a_flipped_bit_made_impossible_is_counted_and_left_out(tmp_path: Path) -> None:
    """LCM logs carry no checksum: a bit flipped in a record's start decodes. The record goes,
    with its input; the DPU's figures stay those of the others, and the report says so."""
    dpu1, dpu2 = small_run()
    good = load_run(str(write_log(tmp_path / "good.lcm", _events(dpu1, dpu2)))).report
    hit = next(r for r in dpu1 if r.process == 1 and r.cycle == 5)  # B, measured, with one input
    hit.start_ns ^= 1 << 60
    damaged = load_run(str(write_log(tmp_path / "bad.lcm", _events(dpu1, dpu2))))
    rep = damaged.report
    assert rep.integrity.malformed == {IMPOSSIBLE: 1}
    assert len(damaged.recorded.records) == 2 * len(dpu1) // 2 + len(dpu2) - 1
    a, b = rep.processes[0], rep.processes[1]
    assert (a.cycles, b.cycles) == (good.processes[0].cycles, good.processes[1].cycles - 1)
    assert a.inputs == good.processes[0].inputs  # the inputs left are still their own records'
    assert b.inputs[0].new + b.inputs[0].stale == b.cycles
    assert b.latency_us.max < 10_000 and rep.dpus[0].elapsed_ms == good.dpus[0].elapsed_ms
    assert f"malformed messages skipped: {IMPOSSIBLE}: 1" in _render(rep)


def test_a_config_whose_values_the_contract_does_not_name_is_malformed(tmp_path: Path) -> None:
    """LCM checks a message's type, not its values: a damaged config of compute mode 4 decodes.
    It is skipped as malformed, and the one re-sent after it (whole) names the run's windows.
    (Found by test_logreader_properties: the analysis had stopped on it with a traceback.)"""
    dpu1, dpu2 = small_run()
    damaged = small_config()
    damaged.dpus[0].compute = 4
    path = write_log(tmp_path / "run.lcm", [*_events(dpu1, dpu2), (CONFIG_CHANNEL, damaged)])
    rep = load_run(str(path), RUN_ID).report
    assert rep.integrity.malformed == {CONFIG_CHANNEL: 1}
    assert rep.compute_modes == {1: "sleep", 2: "sleep"}


def _events(dpu1: list, dpu2: list) -> list[tuple[str, object]]:
    return [(CONFIG_CHANNEL, small_config())] + [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 4)
                                                   + batches(2, dpu2, 2)]  # fmt: skip


def test_tables_are_deterministic_and_show_the_paper(tmp_path: Path) -> None:
    path = _log(tmp_path / "jam.lcm", lockouts=True)
    paper = {1: {"compute_pct": 90.3, "communicate_pct": 9.0, "wait_pct": 0.0, "cycle_ms": 5.0}}
    first, second = _render(load_run(str(path)).report, paper), _render(load_run(str(path)).report, paper)
    assert first == second
    # The paper's row beside ours: cycle paper/ours, % compute paper/ours/delta.
    assert re.search(r"│ +1 │ +5\.00 │ +10\.01 │ +90\.3 │ +60\.0 │ +-30\.3 │", first), first
    assert "C -> B -> A" in first and "overloaded" in first
    assert re.search(r"B +│ a_out +│ +6 │ +2 │ +2 │ +6 │", first)
    clean = _render(load_run(str(_log(tmp_path / "ok.lcm"))).report)
    assert "log damaged" not in clean and "malformed messages skipped: SKEL_STATUS: 1" in clean


def _two_generation_log(path: Path, recs: tuple[list[Rec], list[Rec]] | None = None, warmup: int = 2) -> Path:
    """small_run (or `recs`, its records changed) with the config changed mid-run: A's compute
    4 -> 5 ms (static load 60 -> 70 %), warm-up 2 -> `warmup` cycles. DPU 1 runs generation 3
    for cycles 0..5 and 4 from 6; DPU 2 (20 ms) switches at cycle 3."""
    dpu1, dpu2 = recs or small_run()
    new = small_config(warmup_cycles=warmup, generation=GENERATION + 1)
    new.processes[0].compute_us = 5_000
    old_1, new_1 = batches(1, dpu1[:12], 4), batches(1, dpu1[12:], 4, generation=GENERATION + 1, first_seq=3)
    old_2, new_2 = batches(2, dpu2[:3], 2), batches(2, dpu2[3:], 2, generation=GENERATION + 1, first_seq=2)
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config())]
    events += [(TIMING_CHANNEL, t) for t in old_1 + old_2]
    events += [(CONFIG_CHANNEL, new)] + [(TIMING_CHANNEL, t) for t in new_1 + new_2]
    events += [(REPORT_CHANNEL, report(1, 5)), (REPORT_CHANNEL, report(2, 3))]
    return write_log(path, events)


def test_a_later_windows_faults_say_when_from_the_runs_start(tmp_path: Path) -> None:
    """A fault's at_s counts from the run's first release, in every window: a stall in
    generation 4 read 15 ms into the run, which was 15 ms into its window (60 ms into the run)."""
    dpu1, dpu2 = small_run()
    b8 = next(r for r in dpu1 if r.process == 1 and r.cycle == 8)
    b8.stall_ns = 10 * MS  # a whole minor cycle of DPU 1: a fault of its own
    run = load_run(str(_two_generation_log(tmp_path / "run.lcm", (dpu1, dpu2))))
    stalls = [f for f in run.report.windows[1].faults if f.kind == "stall"]
    # B's cycle started on time, second in its frame: the stall was in its cycle, from its
    # start (80 ms + A's 4.68 ms + 0.1 ms into the run)
    assert [f.at_s for f in stalls] == [pytest.approx(0.08478)], stalls
    # The trace, which holds every window's cycles, puts it where B's cycle 8 starts.
    write_trace(run, tmp_path / "trace.json")
    events = json.loads((tmp_path / "trace.json").read_text())["traceEvents"]
    stall = next(e for e in events if e["ph"] == "i" and e["name"] == "stall")
    b8 = min(e["ts"] for e in events if e["ph"] == "X" and e["tid"] == 1 and e["args"]["cycle"] == 8)
    assert stall["ts"] == pytest.approx(b8)
    # The schedule plot's time axis counts from the run's first release too: DPU 1's curve
    # begins at its window's first frame, 60 ms in, and the stall is marked at 84.78 ms.
    ax = plots.schedule(run).axes[0]
    assert ax.lines[0].get_xdata()[0] == pytest.approx(0.06)
    assert [p.get_x() for p in ax.patches] == [pytest.approx(0.08478)]


def test_generation_windows_split_the_run(tmp_path: Path) -> None:
    rep = load_run(str(_two_generation_log(tmp_path / "run.lcm"))).report
    assert rep.generations == [GENERATION, GENERATION + 1] and rep.generation == GENERATION + 1
    first, last = rep.windows
    assert (first.generation, last.generation) == (GENERATION, GENERATION + 1)
    assert [d.static_load_pct for d in first.dpus] == pytest.approx([60.0, 25.0])
    assert [d.static_load_pct for d in last.dpus] == pytest.approx([70.0, 25.0])
    # Measured cycles (warm-up 2): A 2..5 then 6..9; C 2 then 3..4 (its overrun is in 4).
    assert [p.cycles for p in first.processes] == [4, 4, 1]
    assert [p.cycles for p in last.processes] == [4, 4, 2]
    assert first.faults == [] and [f.kind for f in last.faults] == ["overrun"]
    # From the first measured release to the end of the last measured cycle (work + idle).
    assert first.duration_ms == pytest.approx(40.0) and last.duration_ms == pytest.approx(40.25)
    # The top level is the last window; the JSON carries every window with the same fields.
    assert rep.dpus == last.dpus and rep.processes == last.processes and rep.faults == last.faults
    out = rep.to_json()
    assert [w["generation"] for w in out["windows"]] == [GENERATION, GENERATION + 1]
    for w in out["windows"]:
        assert {"dpus", "processes", "buffers", "chains", "faults", "start_ns", "end_ns"} <= set(w)
    assert out["windows"][1]["dpus"] == out["dpus"] and out["windows"][1]["processes"] == out["processes"]
    assert out["windows"][0]["dpus"][0]["compute_mode"] == "sleep"
    # A DPU sums its own figures over the whole run, across the switch (warm-up once a run): ours,
    # beside them, add up both windows (A 4 + B 2 ms in 4 + 4 cycles; C 5, then 5 and 19 ms).
    assert [row["compute_ms"][1] for row in out["cross_check"]] == pytest.approx([48.0, 29.0])
    text = _render(rep)
    assert text.count("== generation") == 2
    assert text.index(f"== generation {GENERATION} window: 0.040 s") < text.index(
        f"== generation {GENERATION + 1} window: 0.040 s"
    )
    assert "run 42, generation 3: per DPU" in text and "run 42, generation 4: per DPU" in text


def test_a_dpu_behind_at_a_live_switch_counts_the_new_window_from_the_end_of_the_old_work(
    tmp_path: Path,
) -> None:
    """DPU 1's last cycle of generation 3 (B's cycle 5) runs 2.55 ms into generation 4's first
    minor cycle, as a DPU behind its schedule at the switch does. No share of the new window
    counts that time (it read as overhead): the window's measured time begins when that work
    ended, as after warm-up, in the report and the live tables alike."""
    dpu1, dpu2 = small_run()
    late = next(r for r in dpu1 if r.process == 1 and r.cycle == 5)
    late.compute_ns += 5 * MS
    late.idle_ns = 0
    first = next(r for r in dpu1 if r.process == 0 and r.cycle == 6)  # A: generation 4's first
    first.start_ns = late.end_ns + 100 * US  # one cycle at a time
    analysis = load_run(str(_two_generation_log(tmp_path / "run.lcm", (dpu1, dpu2))))
    new = analysis.report.windows[1]
    assert new.generation == GENERATION + 1
    assert new.dpus[0].elapsed_ms == pytest.approx(40.0 - 2.55)  # r9 + 10 ms - (r6 + 2.55 ms)
    assert new.dpus[1].elapsed_ms == pytest.approx(40.25)  # on time: r3 to its overrun's end, r4 + 20.25 ms
    live = RunTally(RUN_ID).update(analysis.recorded, analysis.messages.configs)
    assert live is not None and live.generation == GENERATION + 1
    assert [(d.elapsed_ms, d.shares_pct[0]) for d in live.dpus] == [
        (d.elapsed_ms, d.compute_pct) for d in new.dpus
    ]


def test_the_tables_parquet_and_trace_hold_every_generation(tmp_path: Path) -> None:
    """The timing and receptions tables (the API's, the Parquet files) and the trace held the
    report generation's window alone: 2151 of a pushed run's 5307 cycles. Every window's rows
    now, each with its generation and measured as its own window's config says (generation 4
    warms up 7 cycles: A and B are measured from cycle 7, C, at 20 ms, not at all)."""
    run = load_run(_two_generation_log(tmp_path / "run.lcm", warmup=7))
    every = {(p, k) for p in (0, 1) for k in range(10)} | {(2, k) for k in range(5)}
    old = {(p, k) for p in (0, 1) for k in range(6)} | {(2, k) for k in range(3)}
    want_measured = {(p, k) for p in (0, 1) for k in (2, 3, 4, 5, 7, 8, 9)} | {(2, 2)}
    write_parquet(run, tmp_path / "pq")
    for timing in (run.timing.to_pandas(), pd.read_parquet(tmp_path / "pq" / "timing.parquet")):
        rows = list(zip(timing.process, timing.cycle, strict=True))
        assert sorted(rows) == sorted(every)
        assert [g for g, row in zip(timing.generation, rows, strict=True) if row in old] == [GENERATION] * 15
        assert set(timing.generation) == {GENERATION, GENERATION + 1}
        assert {row for m, row in zip(timing.measured, rows, strict=True) if m} == want_measured
        assert set(timing.process_name) == {"A", "B", "C"}
    for receptions in (run.receptions.to_pandas(), pd.read_parquet(tmp_path / "pq" / "receptions.parquet")):
        gens = {(p, k): g for p, k, g in zip(receptions.process, receptions.cycle, receptions.generation,
                                             strict=True)}  # fmt: skip
        assert len(receptions) == 25 and len(gens) == 25
        assert all(g == (GENERATION if row in old else GENERATION + 1) for row, g in gens.items())
    write_trace(run, tmp_path / "trace.json")
    events = json.loads((tmp_path / "trace.json").read_text())["traceEvents"]
    compute = {(e["tid"], e["args"]["cycle"]) for e in events if e["ph"] == "X" and e["name"] == "compute"}
    assert compute == set(rows)
    assert {e["args"]["name"] for e in events if e["name"] == "thread_name"} == {"A", "B", "C"}


def test_one_generation_tables_are_over_the_runs_own_records(tmp_path: Path) -> None:
    """Warm-up rows included, and no copy of the run's columns (10^7 records: gigabytes)."""
    run = load_run(_log(tmp_path / "run.lcm"))
    assert run.records is run.recorded.records and run.inputs is run.recorded.inputs
    timing = run.timing.to_pandas()
    assert len(timing) == 25 and (~timing.measured).sum() == 2 + 2 + 2  # A, B: cycles 0, 1; C: 0, 1


def test_one_generation_prints_no_window_header(tmp_path: Path) -> None:
    rep = load_run(str(_log(tmp_path / "run.lcm"))).report
    assert len(rep.windows) == 1 and rep.windows[0].dpus == rep.dpus
    text = _render(rep)
    assert "== generation" not in text and "per chain" not in text  # no chain in this system
    assert re.search(r"│ b_out +│ B -> C +│ +1\.0 │ +1\.0 │ +1\.0 │ +0 │ +3 │ +0 │", text)
    assert re.search(r"│ A +│ +4655 │ +4689 │ +4690 │ +5310 │ +5345 │", text)


def test_process_response_slack_and_histograms(tmp_path: Path) -> None:
    out = load_run(str(_log(tmp_path / "run.lcm"))).report.to_json()
    a = out["processes"][0]
    # A: response = start latency (100 + 10 k µs) + 200 + 4000 + 300 µs, k = 2..9
    assert a["response_us"]["p50"] == pytest.approx(4655.0)
    assert a["response_us"]["max"] == pytest.approx(4690.0)
    # slack = 10 ms - response: 5310 .. 5380 µs
    assert a["slack_us"] == {"min": pytest.approx(5310.0), "mean": pytest.approx(5345.0)}
    for name in ("release_latency_us", "response_us"):
        hist = a["histograms"][name]
        assert len(hist["bins"]) == 41 and sum(hist["counts"]) == 8
    assert a["histograms"]["response_us"]["bins"][0] == pytest.approx(4620.0)  # the smallest sample


def test_a_stray_timing_batch_of_an_unknown_generation_is_counted_not_fatal(tmp_path: Path) -> None:
    """A well-formed timing_t of this run with a generation no config names (2**63-1) made
    the whole report fail; it is now counted and the run's tables are as without it."""
    clean_run = load_run(str(_log(tmp_path / "clean.lcm")))
    clean = clean_run.report.to_json()
    dpu1, _ = small_run()
    stray = batches(1, dpu1[:2], 2, generation=2**63 - 1, first_seq=900)
    path = _log(tmp_path / "run.lcm")
    events_log = path.read_bytes()
    write_log(tmp_path / "stray.lcm", [(TIMING_CHANNEL, t) for t in stray])
    (tmp_path / "both.lcm").write_bytes(events_log + (tmp_path / "stray.lcm").read_bytes())
    both = load_run(str(tmp_path / "both.lcm"))
    rep = both.report.to_json()
    assert rep["generation"] == GENERATION
    # Its records are nobody's cycle: not in the tables either.
    assert both.timing.to_pandas().equals(clean_run.timing.to_pandas())
    assert rep["dpus"] == clean["dpus"] and rep["processes"] == clean["processes"]
    assert rep["integrity"]["malformed"].get("SKEL_TIMING (no config for its generation)") == 2
