"""A live view's record store forgets its oldest records on a long run and stays bounded,
while its tables stay `skel report`'s for the whole run and its search for faults still
reads every record."""

from __future__ import annotations

import numpy as np
import pytest
from analysis_synth import MS, RUN_ID, Rec, batches, small_config, small_run, status
from hypothesis import given, settings
from hypothesis import strategies as st

import skelmsg
from skeleton.analysis.measure.report import build_report
from skeleton.analysis.read.records import decode_run, lost_batches, seq_ranges
from skeleton.host.cli.watch import Heard
from skeleton.host.live import listener as listener_module
from skeleton.host.live.listener import fault_key
from skeleton.host.live.recordstore import HARD_FACTOR, RecordStore, _heard_first
from skelmsg.contract import CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL

from .test_watch import _same_tables

KEEP = 64


def _long_run(cycles: int) -> list[bytes]:
    """small_run over `cycles` cycles, in batches of both DPUs interleaved by time, with a
    stall of DPU 1 and an overrun of DPU 2 in the middle: faults a search must find long
    after the store forgot the run's start."""
    dpu1, dpu2 = small_run(cycles=cycles)
    stalled = next(r for r in dpu1 if r.process == 1 and r.cycle == cycles // 2)
    stalled.stall_ns = 8 * MS
    late: Rec = dpu2[len(dpu2) // 2 + 3]
    late.compute_ns, late.idle_ns, late.flags = 19 * MS, 0, skelmsg.timing_t.FLAG_OVERRUN
    late.slack_ns = late.release_ns + 20 * MS - late.end_ns
    ones, twos = batches(1, dpu1, 4), batches(2, dpu2, 2)
    return [t.encode() for pair in zip(ones[::2], ones[1::2], twos, strict=False) for t in pair]


def test_a_long_run_is_held_in_bounded_memory_and_its_tables_and_faults_are_the_whole_runs() -> None:
    config = small_config()
    messages = _long_run(cycles=400)
    whole = decode_run(messages, RUN_ID)
    expected = build_report(config, whole)
    heard = Heard(keep_events=False)
    heard.listener.keep_records = KEEP
    heard.handle(CONFIG_CHANNEL, config.encode())
    most = 0
    for at in range(0, len(messages), 3):
        for data in messages[at : at + 3]:
            heard.handle(TIMING_CHANNEL, data)
        tables = heard.refresh()
        heard.find_faults()
        assert heard.store is not None
        most = max(most, heard.store.n_held)
    store = heard.store
    assert store is not None and tables is not None
    assert store.first > 0 and most < 2 * KEEP and store.unread == 0
    assert store.n_records == len(whole.records) and store.run().lost_batches == whole.lost_batches == []
    _same_tables(tables, expected)
    wanted = {fault_key(f) for f in expected.faults}
    assert {"stall", "overrun"} <= {f.kind for f in expected.faults}
    # (the DPUs are also lost to the live view: it heard no heartbeat of them)
    assert {fault_key(f) for f in heard.listener.found if f.kind != "dpu_lost"} == wanted
    assert all(f.at_s is None or f.at_s < 4 for f in heard.listener.found)  # from the run's first release


def test_readers_behind_by_the_hard_bound_lose_records_counted() -> None:
    store = RecordStore(RUN_ID, keep=16)
    messages = _long_run(cycles=100)
    for data in messages:
        store.add([data])
        assert store.n_held <= HARD_FACTOR * 16 + 6
    assert store.unread == store.first > 0  # nobody read any: each forgotten one counted
    store.searched = store.n_records
    store.forget()
    assert store.n_held == 16


def test_a_view_taken_before_forgetting_stays_whole() -> None:
    store = RecordStore(RUN_ID, keep=16)
    for data in _long_run(cycles=20):
        store.add([data])
    before = store.run()
    copy = {name: np.array(before.records[name]) for name in ("release_ns", "compute_ns")}
    inputs = np.array(before.inputs["record"])
    store.searched = store.n_records
    store.forget()
    assert store.first > 0
    assert all(np.array_equal(before.records[name], copy[name]) for name in copy)
    assert np.array_equal(before.inputs["record"], inputs)
    after = store.run()
    held = decode_run(_long_run(cycles=20), RUN_ID).records[store.first :]
    assert np.array_equal(after.records["release_ns"], held["release_ns"])
    assert after.inputs["record"].max() < len(after.records) and after.origin_ns == before.origin_ns


@settings(max_examples=200, deadline=None)
@given(st.lists(st.tuples(st.integers(1, 3), st.integers(0, 40)), max_size=80))
def test_batches_heard_as_runs_are_the_logs_batches(heard: list[tuple[int, int]]) -> None:
    """Each DPU's batch_seqs kept as runs (bounded by the gaps, not the batches) say what
    the log's arrays say: which were heard twice, and which were lost."""
    runs: dict[int, list[tuple[int, int]]] = {}
    firsts = [_heard_first(runs.setdefault(d, []), s) for d, s in heard]
    assert firsts == [(d, s) not in heard[:i] for i, (d, s) in enumerate(heard)]
    dpus = np.array([d for d, _ in heard], dtype=np.int64)
    seqs = np.array([s for _, s in heard], dtype=np.int64)
    assert {d: r for d, r in runs.items() if r} == seq_ranges(dpus, seqs)
    store = RecordStore(RUN_ID)
    store.seqs = runs
    assert lost_batches(dpus, seqs, {2: 45}) == store.run({2: 45}).lost_batches


def test_the_statuses_are_forgotten_with_the_records_but_the_first_to_name_a_lockout(
        monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(listener_module, "STATUSES_KEEP_NS", 500 * MS)
    config = small_config()
    messages = _long_run(cycles=400)
    heard = Heard(keep_events=False)
    heard.listener.keep_records = KEEP
    heard.handle(CONFIG_CHANNEL, config.encode())
    for at in range(0, len(messages), 3):
        for data in messages[at : at + 3]:
            heard.handle(TIMING_CHANNEL, data)
            beat = status(2, [(2, 1, 7)] if at == 30 else [])
            beat.utc_ns = int(decode_run([data], RUN_ID).records["release_ns"].max())
            heard.handle(STATUS_CHANNEL, beat.encode())
        heard.refresh()
        heard.find_faults()
    store = heard.store
    assert store is not None and store.held_from_ns is not None and store.first > 0
    statuses = heard.listener.statuses
    named = [s for s in statuses if s.lockouts]
    assert len(named) == 1 and named[0].utc_ns < store.held_from_ns - 500 * MS
    assert all(s.utc_ns >= store.held_from_ns - 500 * MS for s in statuses if not s.lockouts)
    assert len(statuses) < len(messages) // 4
    assert any(f.kind == "lockout" and f.process == "C" for f in heard.listener.found)
