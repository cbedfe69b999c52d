"""latency.py (buffer transport latency, loss, clock offsets) and chains.py (end-to-end
chain latency by lineage) on hand-made synthetic runs, and both on a real SERVO run."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from analysis_synth import MS, RUN_ID, US, Rec, batches, chain, clock_offset, small_config, write_log
from rich.console import Console

from skeleton.analysis.measure.chains import ChainMetrics, ChainRecords, chain_metrics
from skeleton.analysis.measure.latency import (
    NO_OFFSETS,
    BufferMetrics,
    ClockOffsets,
    buffer_metrics,
    buffer_parts,
    release_skips,
)
from skeleton.analysis.measure.metrics import input_counts, measured, process_metrics
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.read.records import FLAG_RELEASE_SKIPPED, decode_run
from skeleton.analysis.views.tables import print_report
from skeleton.host.model import from_config
from skelmsg.contract import CLOCK_CHANNEL, CONFIG_CHANNEL, TIMING_CHANNEL


def _buffers(records: Any, inputs: Any, config: Any, run_records: Any = None) -> list[BufferMetrics]:
    """The buffer table of a window of `records`, its skipped releases looked up in `run_records`."""
    everything = records if run_records is None else run_records
    system = from_config(config)
    counted = input_counts(process_metrics(records, inputs, system))
    parts = buffer_parts(records, inputs, system)
    return buffer_metrics(parts, system, release_skips(everything), counted)


def _chains(records: Any, inputs: Any, config: Any, clock: ClockOffsets = NO_OFFSETS) -> list[ChainMetrics]:
    """The chain table of a window of `records`."""
    system = from_config(config)
    return chain_metrics(ChainRecords.of(records, inputs, system, measured(records, system)), system, clock)

T0 = 1_000 * MS  # host clock
TRUE_US = [100, 200, 300, 400]  # b_out's true transport latency, B (DPU 1) -> C (DPU 2), per cycle


def _cross_dpu_log(path: Path, dpu1_offsets: list[tuple[int, int]] | None) -> Path:
    """B (DPU 1) publishes b_out seq k at host time T0 + 10 k ms + 1 ms; C (DPU 2) receives
    it TRUE_US[k] later. DPU 1's clock runs ahead of the host by 5 ms, and by 6 ms from
    cycle 2 on; DPU 2's clock is the host's. `dpu1_offsets`: the estimates (host time,
    offset) put in the log for DPU 1; None: no SKEL_CLOCK message at all."""
    dpu1, dpu2 = [], []
    for k, true_us in enumerate(TRUE_US):
        ahead = 5 * MS if k < 2 else 6 * MS
        r = T0 + k * 10 * MS
        b = Rec(1, k, k, r + ahead, r + ahead, compute_ns=1 * MS, inputs=[(0, k, 1, 0, 1, 0, 0)])
        dpu1.append(b)
        send = r + 1 * MS
        seen = (1, k, 1, 0, 1, send + ahead, send + true_us * US)
        dpu2.append(Rec(2, k, k, r, r + 2 * MS, compute_ns=1 * MS, inputs=[seen]))
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config(warmup_cycles=0))]
    if dpu1_offsets is not None:
        events += [(CLOCK_CHANNEL, clock_offset(2, T0 - 1000 * MS, 0))]
        events += [(CLOCK_CHANNEL, clock_offset(1, at, off)) for at, off in dpu1_offsets]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 2) + batches(2, dpu2, 2)]
    return write_log(path, events)


def _b_out(path: Path) -> dict:
    return next(b for b in load_run(path).report.to_json()["buffers"] if b["buffer"] == "b_out")


def test_clock_offset_of_the_writers_dpu_is_removed(tmp_path: Path) -> None:
    # Estimates: +5 ms long before the run, +6 ms between cycle 1 and cycle 2.
    b_out = _b_out(_cross_dpu_log(tmp_path / "run.lcm", [(T0 - 1000 * MS, 5 * MS), (T0 + 15 * MS, 6 * MS)]))
    (reader,) = b_out["readers"]
    assert (b_out["writer"], reader["process"], reader["samples"], b_out["published"]) == ("B", "C", 4, 4)
    lat = reader["latency_us"]
    assert lat["p50"] == pytest.approx(250.0) and lat["max"] == pytest.approx(400.0)
    assert lat["p99"] == pytest.approx(300 + 0.97 * 100)
    assert b_out["latency_us"] == lat  # one reader: the pooled figures are its own
    assert sum(reader["histogram"]["counts"]) == 4 and len(reader["histogram"]["bins"]) == 41


def test_without_estimates_every_dpu_is_on_the_host_clock(tmp_path: Path) -> None:
    (reader,) = _b_out(_cross_dpu_log(tmp_path / "run.lcm", None))["readers"]
    # The writer's clock is ahead by 5 ms (cycles 0, 1) and 6 ms (2, 3): nothing removes it.
    raw = sorted([100 - 5000, 200 - 5000, 300 - 6000, 400 - 6000])
    assert reader["latency_us"]["max"] == pytest.approx(raw[-1])
    assert reader["latency_us"]["p50"] == pytest.approx((raw[1] + raw[2]) / 2)


def test_the_estimate_in_force_is_the_latest_at_or_before_the_time() -> None:
    clock = ClockOffsets([(1, 100, 5), (1, 1000, 7), (3, 0, -2)])
    # On DPU 1's clock the estimates were made at 105 and 1007; before the first, the first.
    assert clock.offset_ns(1, np.array([0, 104, 105, 1006, 1007, 5000])).tolist() == [5, 5, 5, 5, 7, 7]
    assert clock.to_host(2, np.array([10])).tolist() == [10]  # no estimate: offset 0
    assert clock.to_host_many(np.array([1, 3, 2]), np.array([2000, 10, 10])).tolist() == [1993, 12, 10]
    assert clock.latest() == {1: 7, 3: -2}
    # An estimate within half its round trip is indistinguishable from 0 (one machine).
    near = ClockOffsets([(1, 0, 40_000, 200_000), (2, 0, 5_000_000, 200_000), (3, 0, -100_000, 200_000)])
    assert near.latest() == {1: 0, 2: 5_000_000, 3: 0}
    times = np.full(3, 10**9)
    moved = near.to_host_many(np.array([1, 2, 3]), times)
    assert moved.tolist() == [10**9, 10**9 - 5_000_000, 10**9] and times.tolist() == [10**9] * 3
    assert near.to_host(1, times) is not times  # a DPU of no offset: its times, as a copy
    # A clock that drifted past the error later in the run: its earlier times keep offset 0.
    assert ClockOffsets([(1, 0, 0), (1, 1000, 9)]).to_host(1, np.array([500, 2000])).tolist() == [500, 1991]


def test_loss_separates_superseded_from_lost() -> None:
    config = small_config(warmup_cycles=1)
    # C reads b_out: (seq, new, dropped, received) per cycle; cycle 0 is warm-up.
    seen = [(0, 1, 0, 1), (0, 0, 0, 0), (2, 1, 1, 2), (5, 1, 2, 1), (5, 0, 0, 0), (9, 1, 3, 4)]
    recs = [Rec(2, k, k, k * 20 * MS, k * 20 * MS, inputs=[(1, *s)]) for k, s in enumerate(seen)]
    writer = [Rec(1, k, k, k * 10 * MS, k * 10 * MS) for k in range(10)]
    run = decode_run([t.encode() for t in batches(1, writer, 4) + batches(2, recs, 4)], RUN_ID)
    b_out = next(b for b in _buffers(run.records, run.inputs, config) if b.buffer == "b_out")
    (c,) = b_out.readers
    # Measured cycles 1..5: new 3, dropped 1 + 2 + 3 = 6, received 2 + 1 + 4 = 7:
    # superseded = 7 - 3 = 4 (seq 1; 6, 7, 8), lost = 6 - 4 = 2 (seqs 3 and 4 never came).
    assert (c.new, c.dropped, c.received, c.superseded, c.lost) == (3, 6, 7, 4, 2)
    assert (b_out.published, b_out.dropped, b_out.lost) == (9, 6, 2)
    assert c.samples == 3  # one per new cycle, never one per stale cycle


def test_a_sequence_its_writer_never_sent_is_not_lost() -> None:
    # A data-synchronised writer skips its releases 3 and 7 (cycle skipping after a stall): its
    # readers see those sequences dropped, but nothing was lost on the link.
    config = small_config(warmup_cycles=1)
    seen = [(0, 1, 0, 1), (2, 1, 1, 2), (5, 1, 2, 1), (9, 1, 3, 3)]
    recs = [Rec(2, k, k, k * 20 * MS, k * 20 * MS, inputs=[(1, *s)]) for k, s in enumerate(seen)]
    writer = [Rec(1, k, k, k * 10 * MS, k * 10 * MS, flags=FLAG_RELEASE_SKIPPED if k in (3, 7) else 0)
              for k in range(10)]
    run = decode_run([t.encode() for t in batches(1, writer, 4) + batches(2, recs, 4)], RUN_ID)
    b_out = next(b for b in _buffers(run.records, run.inputs, config) if b.buffer == "b_out")
    (c,) = b_out.readers
    # Measured cycles 1..3 dropped 1 + 2 + 3 = 6 (seqs 1; 3, 4; 6, 7, 8): 3 and 7 were never
    # sent, 1, 6 and 8 were received and superseded (6 received, 3 new), and 4 was lost.
    assert (c.new, c.dropped, c.received, c.unpublished, c.superseded) == (3, 6, 6, 2, 3)
    assert c.lost == 1 and b_out.lost == 1
    # A window after a live switch holds no record of releases skipped before it: the run's do.
    window = run.records.copy()
    window["flags"] &= ~FLAG_RELEASE_SKIPPED
    alone = next(b for b in _buffers(window, run.inputs, config) if b.buffer == "b_out")
    assert (alone.readers[0].unpublished, alone.lost) == (0, 3)
    whole = _buffers(window, run.inputs, config, run_records=run.records)
    assert next(b for b in whole if b.buffer == "b_out").lost == 1


def _lineage_run(c_ahead_ns: int) -> tuple[list[Rec], list[Rec]]:
    """Chain A -> B -> C (a_out, b_out). A's seq s is sent at host T0 + 10 s ms + 4 ms.
    B's cycles read A's seqs [0, 0, 1, 3, 4, 4]; C's cycles read B's seqs
    [0, 1, 3, 3, 5, 9] (new = [1, 1, 1, 0, 1, 1]; there is no B cycle 9).
    C runs on DPU 2, whose clock is c_ahead_ns ahead of the host."""
    def sent_a(s: int) -> int:
        return T0 + s * 10 * MS + 4 * MS

    dpu1 = []
    for k, s in enumerate([0, 0, 1, 3, 4, 4]):
        r = T0 + k * 10 * MS
        dpu1.append(Rec(0, k, k, r, r, compute_ns=4 * MS, inputs=[(2, -1, 0, 0, 0, 0, 0)]))
        dpu1.append(Rec(1, k, k, r, r + 5 * MS, inputs=[(0, s, 1, 0, 1, sent_a(s), sent_a(s) + 50 * US)]))
    dpu2 = []
    for j, (s, new) in enumerate(zip([0, 1, 3, 3, 5, 9], [1, 1, 1, 0, 1, 1], strict=True)):
        r = T0 + j * 20 * MS + c_ahead_ns
        blocked = 200 * US if j == 2 else 0
        dpu2.append(Rec(2, j, j, r, r + 15 * MS, comm_in_ns=100 * US, blocked_ns=blocked,
                        inputs=[(1, s, new, 0, new, 0, 0)]))  # fmt: skip
    return dpu1, dpu2


def test_chain_latency_follows_the_lineage_back_to_the_head() -> None:
    config = small_config(warmup_cycles=0)
    config.nchains, config.chains = 1, [chain("A-B-C", [0, 1, 2])]
    dpu1, dpu2 = _lineage_run(c_ahead_ns=5 * MS)
    run = decode_run([t.encode() for t in batches(1, dpu1, 5) + batches(2, dpu2, 5)], RUN_ID)
    (m,) = _chains(run.records, run.inputs, config, ClockOffsets([(2, 0, 5 * MS)]))
    assert (m.name, m.processes, m.buffers) == ("A-B-C", ["A", "B", "C"], ["a_out", "b_out"])
    # C0 carries A0; C1 A0 again (not a first arrival); C2 A3; C3 is stale; C4 A4;
    # C5's B cycle 9 is not in the log: broken.
    assert m.series is not None
    assert m.series.tail_cycle.tolist() == [0, 2, 4] and m.series.head_cycle.tolist() == [0, 3, 4]
    # use = C's start + comm_in + blocked (host clock) - A's send
    expected_us = [15_100 - 4_000, 55_300 - 34_000, 95_100 - 44_000]
    assert (m.series.latency_ns / 1000).tolist() == expected_us
    assert (m.samples, m.broken) == (3, 1)
    assert m.latency_us.p50 == pytest.approx(21_300.0) and m.latency_us.max == pytest.approx(51_100.0)
    assert m.latency_us.p99 == pytest.approx(21_300 + 0.98 * 29_800)
    # Without the offset estimate C's clock is 5 ms ahead and so is every sample.
    (raw,) = _chains(run.records, run.inputs, config)
    assert raw.series is not None
    assert (raw.series.latency_ns / 1000).tolist() == [x + 5000 for x in expected_us]


def test_chain_in_report_json_has_summary_not_series(tmp_path: Path) -> None:
    config = small_config(warmup_cycles=0)
    config.nchains, config.chains = 1, [chain("A-B-C", [0, 1, 2])]
    dpu1, dpu2 = _lineage_run(c_ahead_ns=0)
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, config)]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 5) + batches(2, dpu2, 5)]
    rep = load_run(write_log(tmp_path / "run.lcm", events)).report
    (c,) = rep.to_json()["chains"]
    assert (c["name"], c["processes"], c["samples"]) == ("A-B-C", ["A", "B", "C"], 3)
    assert c["latency_us"]["max"] == pytest.approx(51_100.0) and "series" not in c
    assert rep.chains[0].series is not None and len(rep.chains[0].series.use_ns) == 3
    json.dumps(rep.to_json())
    console = Console(file=io.StringIO(), width=120, record=True, color_system=None)
    print_report(rep, console=console)
    assert re.search(r"│ A-B-C +│ A -> B -> C +│ +3 │ +21300 │ +50504 │ +51100 │ +1 │", console.export_text())
