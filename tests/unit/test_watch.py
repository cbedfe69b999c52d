"""skel watch: a replayed run's final table equals `skel report`'s, the live view shows a live
run and its faults, and the incremental record store equals the one-shot decode."""

from __future__ import annotations

import io
import re
import time

import numpy as np
import pytest
from analysis_synth import GENERATION, MS, RUN_ID, batches, small_config, small_run, status
from hypothesis import example, given, settings
from hypothesis import strategies as st
from rich.console import Console

from skeleton.analysis.measure.report import RunReport, build_report
from skeleton.analysis.measure.run import IMPOSSIBLE
from skeleton.analysis.measure.tally import GenerationTally, RunTally
from skeleton.analysis.read.records import decode_run, impossible
from skeleton.host.cli.watch import Heard, _FaultFinder
from skeleton.host.cli.watch_view import BAR_WIDTH, MIN_BAR_WIDTH, render
from skeleton.host.live.recordstore import RecordStore
from skelmsg.contract import CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL


def _synthetic_messages() -> list[bytes]:
    dpu1, dpu2 = small_run()
    return [t.encode() for t in batches(1, dpu1, 3) + batches(2, dpu2, 2)]


def test_record_store_in_chunks_equals_one_decode() -> None:
    msgs = _synthetic_messages()
    whole = decode_run(msgs, RUN_ID)
    store = RecordStore(RUN_ID)
    for first in range(0, len(msgs), 2):
        store.add(msgs[first : first + 2])
    store.add(msgs[:3])  # heard twice: counted as duplicates, never twice in the records
    run = store.run()
    assert np.array_equal(run.records, whole.records)
    assert np.array_equal(run.inputs, whole.inputs)
    assert run.batches == whole.batches and run.generations == whole.generations
    assert run.duplicates == 3 and run.lost_batches == []
    assert store.run({1: len(batches(1, small_run()[0], 3)) + 2}).lost_batches[-1]["dpu"] == 1


def test_heard_messages_give_the_tables_the_faults_and_a_view() -> None:
    heard = Heard(keep_events=False)
    config = small_config()
    heard.handle(CONFIG_CHANNEL, config.encode())
    heard.handle(STATUS_CHANNEL, status(2, [(2, 1, 7)]).encode())
    for data in _synthetic_messages():
        heard.handle(TIMING_CHANNEL, data)
    heard.handle(TIMING_CHANNEL, b"junk")
    tables = heard.refresh()
    report = heard.find_faults()
    assert tables is not None and report is not None and heard.run_id == RUN_ID
    expected = build_report(config, decode_run(_synthetic_messages(), RUN_ID), [status(2, [(2, 1, 7)])])
    assert [d.shares_pct[0] for d in tables.dpus] == [d.compute_pct for d in expected.dpus]
    assert report.integrity.malformed == {TIMING_CHANNEL: 1}
    assert any("lockout: C (DPU 2) at cycle 7, waiting on b_out" in text for _, text in heard.faults)
    console = Console(width=160, record=True, file=io.StringIO())
    console.print(render(heard, "udpm://x"))
    text = console.export_text()
    assert f"run {RUN_ID}" in text and "hungry" not in text and "lockout: C" in text
    assert "faults searched" not in text  # the search covered every record heard
    heard.handle(TIMING_CHANNEL, batches(1, small_run(cycles=12)[0][20:], 4, first_seq=100)[0].encode())
    heard.refresh()
    console.print(render(heard, "udpm://x"))
    assert f"faults searched in the first {heard.covered}" in console.export_text()


def test_records_with_impossible_times_are_left_out_of_the_live_view_and_counted() -> None:
    """LCM carries no checksum: a flipped bit in a record's start decodes (2^60 ns: 36 years
    elapsed, 0 % shares). Live, as in `skel report`, the record goes, with its input, is counted
    under the report's key and said so; the tables are those of the other records. A batch heard
    alone whose every record is 18 minutes late (on its own it bounds itself: its median is that
    lateness) is judged against what was held before it."""
    config = small_config()
    dpu1, dpu2 = small_run()
    hit = next(r for r in dpu1 if r.process == 1 and r.cycle == 5)  # B, measured, with one input
    clean = [t.encode() for t in batches(1, [r for r in dpu1 if r is not hit], 3) + batches(2, dpu2, 2)]
    hit.start_ns ^= 1 << 60
    heard = Heard(keep_events=False)
    heard.handle(CONFIG_CHANNEL, config.encode())
    for t in batches(1, dpu1, 3) + batches(2, dpu2, 2):
        heard.handle(TIMING_CHANNEL, t.encode())
    tables = heard.refresh()
    expected = build_report(config, decode_run(clean, RUN_ID))
    assert tables is not None and heard.store is not None
    assert heard.store.impossible == 1 and heard.store.n_records == len(dpu1) + len(dpu2) - 1
    _same_tables(tables, expected)
    assert tables.dpus[0].elapsed_ms < 1000
    late = small_run(cycles=12)[0][20:]
    for r in late:
        r.start_ns += 1 << 40
    lone = batches(1, late, len(late), first_seq=len(batches(1, dpu1, 3)))[0].encode()
    assert not impossible(decode_run([lone], RUN_ID).records, 0).any()  # alone, it would pass
    heard.handle(TIMING_CHANNEL, lone)
    tables = heard.refresh()
    report = heard.find_faults()
    assert tables is not None and report is not None
    assert heard.store.impossible == 1 + len(late) and heard.lost_batches == 0
    _same_tables(tables, expected)
    assert report.integrity.malformed == {IMPOSSIBLE: 1 + len(late)}
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(render(heard, "udpm://x"))
    assert f"malformed messages skipped: {IMPOSSIBLE}: {1 + len(late)}" in console.export_text()


def test_on_a_narrow_terminal_the_bars_shrink_not_the_figures() -> None:
    """At 80 columns the utilization bar gave up nothing and the DPU ids and percentages were
    cut to '…' (walk-through); now the bar shrinks first, and is whole where there is room."""
    heard = Heard(keep_events=False)
    heard.handle(CONFIG_CHANNEL, small_config().encode())
    for data in _synthetic_messages():
        heard.handle(TIMING_CHANNEL, data)
    heard.refresh()
    for width, bar in ((80, MIN_BAR_WIDTH), (160, BAR_WIDTH)):
        console = Console(width=width, record=True, file=io.StringIO())
        console.print(render(heard, "udpm://x"))
        rows = [line for line in console.export_text().splitlines() if "█" in line and line.startswith("│")]
        assert len(rows) == 2 and all("…" not in row for row in rows), rows
        assert [len(row.split("│")[3]) - 2 for row in rows] == [bar] * 2, rows  # less the cell's padding
        assert all(re.search(r"│\s+\d+\.\d │", row) for row in rows), rows


def _same_tables(tables: GenerationTally, report: RunReport) -> None:
    """The live tables hold exactly the report's figures for the same records."""
    assert [(d.id, d.records, d.overruns, d.shares_pct, d.elapsed_ms) for d in tables.dpus] == [
        (d.id, d.records, d.overruns, (d.compute_pct, d.communicate_pct, d.wait_pct, d.overhead_pct),
         d.elapsed_ms)
        for d in report.dpus
    ]
    assert [(p.id, p.cycles, p.overruns, p.late, p.too_late, p.latency_us) for p in tables.processes] == [
        (p.id, p.cycles, p.overruns, p.late, p.too_late, p.latency_us) for p in report.processes
    ]


@settings(max_examples=60, deadline=None)
@example(order=[*range(1, 10), 0], sizes=[9, 1])  # the window opens earlier at the last batch
@given(st.permutations(range(10)), st.lists(st.integers(1, 4), min_size=10, max_size=10))
def test_the_tables_tallied_chunk_by_chunk_equal_the_reports(order: list[int], sizes: list[int]) -> None:
    """Batches in any order, refreshed after chunks of any size: the report's figures every
    time. A's first release is a cycle early, so the batch holding it opens DPU 1's
    measurement window a cycle earlier: heard late, the DPU is tallied again."""
    dpu1, dpu2 = small_run()
    dpu1[0].release_ns -= 10 * MS
    msgs = [t.encode() for t in batches(1, dpu1, 3) + batches(2, dpu2, 2)]
    assert len(msgs) == len(order)
    msgs = [msgs[i] for i in order]
    config = small_config()
    store, tally, at = RecordStore(RUN_ID), RunTally(RUN_ID), 0
    for size in sizes:
        store.add(msgs[at : at + size])
        at += size
        tables = tally.update(store.run(), {config.generation: config})
        assert tables is not None
        _same_tables(tables, build_report(config, store.run()))
        if at >= len(msgs):
            break


def test_the_tables_follow_the_newest_generation() -> None:
    dpu1, dpu2 = small_run()
    old, new = small_config(), small_config(generation=GENERATION + 1)
    store, tally = RecordStore(RUN_ID), RunTally(RUN_ID)
    store.add([t.encode() for t in batches(1, dpu1[:10], 3) + batches(2, dpu2[:2], 2)])
    assert tally.update(store.run(), {old.generation: old}).generation == GENERATION
    later = batches(1, dpu1[10:], 3, generation=new.generation, first_seq=10)
    store.add([t.encode() for t in later + batches(2, dpu2[2:], 2, generation=new.generation, first_seq=10)])
    tables = tally.update(store.run(), {old.generation: old, new.generation: new})
    assert tables.generation == new.generation
    _same_tables(tables, build_report(new, store.run(), configs={old.generation: old}))


def test_the_view_says_its_tables_are_a_later_generations_window() -> None:
    """After a live switch the view's tables are the new generation's, measured from its own
    start: the head says so (a walk-through read the time begun again as the run's)."""
    dpu1, dpu2 = small_run()
    old, new = small_config(), small_config(generation=GENERATION + 1)
    heard = Heard(keep_events=False)
    heard.handle(CONFIG_CHANNEL, old.encode())
    for t in batches(1, dpu1[:10], 3) + batches(2, dpu2[:2], 2):
        heard.handle(TIMING_CHANNEL, t.encode())
    heard.handle(CONFIG_CHANNEL, new.encode())
    for t in (batches(1, dpu1[10:], 3, generation=new.generation, first_seq=10)
              + batches(2, dpu2[2:], 2, generation=new.generation, first_seq=10)):
        heard.handle(TIMING_CHANNEL, t.encode())
    heard.refresh()
    console = Console(width=200, record=True, file=io.StringIO())
    console.print(render(heard, "udpm://x"))
    text = console.export_text()
    assert (f"generation {GENERATION + 1} (switched live from {GENERATION}; `skel report` has every window) "
            "· measured") in text, text


def test_a_new_run_shows_none_of_the_old_runs_tables() -> None:
    heard = Heard(keep_events=False)
    heard.handle(CONFIG_CHANNEL, small_config().encode())
    for data in _synthetic_messages():
        heard.handle(TIMING_CHANNEL, data)
    assert heard.refresh() is not None and heard.find_faults() is not None and heard.covered > 0
    heard.handle(TIMING_CHANNEL, _empty_batch(RUN_ID + 1))  # the next run: no records yet
    assert heard.run_id == RUN_ID + 1
    assert heard.refresh() is None and heard.tables is None and heard.lost_batches == 0 and heard.covered == 0


def _empty_batch(run_id: int) -> bytes:
    """A timing batch of `run_id` that holds no record."""
    t = batches(1, small_run()[0][:1], 3, run_id=run_id)[0]
    for name in t.__slots__:
        value = getattr(t, name)
        if isinstance(value, list):
            setattr(t, name, [])
    t.n, t.ninputs = 0, 0
    return t.encode()


def test_an_error_in_the_search_for_faults_stops_skel_watch(monkeypatch: pytest.MonkeyPatch) -> None:
    heard = Heard(keep_events=False)

    def broken() -> None:
        raise RuntimeError("a bug in the analysis")

    monkeypatch.setattr(heard, "find_faults", broken)
    monkeypatch.setattr(heard.listener, "faults_due", lambda: True)
    finder = _FaultFinder(heard)
    deadline = time.monotonic() + 10
    while finder.error is None and time.monotonic() < deadline:
        time.sleep(0.05)
    with pytest.raises(RuntimeError, match="a bug in the analysis"):
        finder.check()
