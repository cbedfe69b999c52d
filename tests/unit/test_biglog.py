"""bench/biglog.py: the long run `make bench` analyses is the short one repeated, every
time, cycle and sequence moved on and nothing else changed."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
from analysis_synth import batches, small_config, small_run, write_log
from conftest import REPO

from skeleton.analysis.read.logreader import read_log
from skeleton.analysis.read.records import load_records
from skelmsg.contract import CONFIG_CHANNEL, TIMING_CHANNEL

sys.path.insert(0, str(REPO / "bench"))
from biglog import grow

COPIES = 3


def test_a_grown_run_repeats_the_durations_and_moves_only_times_and_counters(tmp_path: Path) -> None:
    dpu1, dpu2 = small_run()
    # 0x5EED ns of blocked time followed by a cycle that waited none: the encoded bytes
    # hold 5E ED 00 00 00 00 00 00, which a search for a sentinel of those bytes took for
    # a field that comes later (the grown run then had 10^14 ns of compute).
    dpu1[7].blocked_ns, dpu1[8].blocked_ns = 0x5EED, 0
    timing = batches(1, dpu1, 5) + batches(2, dpu2, 5)
    timing[0].event_ns[2] = timing[0].release_ns[2] - 3000  # an event cycle's event: a time, moved too
    events = [(CONFIG_CHANNEL, small_config())] + [(TIMING_CHANNEL, t) for t in timing]
    source = load_records(read_log(write_log(tmp_path / "short.lcm", events))).records
    held = grow(tmp_path / "short.lcm", tmp_path / "long.lcm", COPIES * len(source))
    grown = load_records(read_log(tmp_path / "long.lcm")).records
    assert held == len(grown) == COPIES * len(source)
    for name in ("comm_in_ns", "blocked_ns", "asked_ns", "compute_ns", "comm_out_ns", "idle_ns", "slack_ns",
                 "flags"):  # fmt: skip
        assert np.array_equal(np.sort(grown[name]), np.sort(np.tile(source[name], COPIES))), name

    def since_event(r: np.ndarray) -> np.ndarray:  # -1 (no event) kept as it is
        return np.where(r["event_ns"] >= 0, r["release_ns"] - r["event_ns"], r["event_ns"])

    assert np.count_nonzero(source["event_ns"] >= 0) == 1
    assert np.array_equal(np.sort(since_event(grown)), np.sort(np.tile(since_event(source), COPIES)))
    for process in np.unique(source["process"]).tolist():
        cycles = np.sort(grown["cycle"][grown["process"] == process])
        assert len(cycles) == COPIES * np.count_nonzero(source["process"] == process)
        assert np.all(np.diff(cycles) > 0), f"process {process}: a cycle twice in {cycles}"
        lateness = grown["start_ns"] - grown["release_ns"]
        assert np.array_equal(np.sort(lateness), np.sort(np.tile(source["start_ns"] - source["release_ns"],
                                                                 COPIES)))  # fmt: skip
