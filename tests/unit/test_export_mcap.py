"""tests/e2e/test_export_mcap_dpus.py's tests that start no skel-dpu (it says what they check)."""

from __future__ import annotations

import tracemalloc
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from analysis_synth import GENERATION, batches, small_config, small_run, status, write_log
from mcap.reader import make_reader
from mcap_ros2.decoder import DecoderFactory

import skelmsg
from skeleton.analysis.measure.run import load_run
from skeleton.analysis.read.lcmjson import to_json, to_json_many
from skeleton.analysis.views.export_mcap import _pairs, export
from skelmsg.contract import CONFIG_CHANNEL, TIMING_CHANNEL


def _timing(path: Path) -> list[tuple[Any, Any, Any]]:
    """(channel, message, decoded) of every /timing message, decoded as Foxglove would."""
    with open(path, "rb") as f:
        reader = make_reader(f, decoder_factories=[DecoderFactory()])
        summary = reader.get_summary()
        assert summary is not None
        topics = [c.topic for c in summary.channels.values() if c.topic.startswith("/timing/")]
        return [(c, m, d) for _, c, m, d in reader.iter_decoded_messages(topics, log_time_order=False)]


def test_a_process_of_an_earlier_generation_only_keeps_its_name(tmp_path: Path) -> None:
    """A push that removed C: C's records, of the first window, are still C's topic, not
    'process 2' for want of a name in the last config."""
    dpu1, dpu2 = small_run()
    old, new = small_config(), small_config(generation=GENERATION + 1)
    new.processes = [p for p in new.processes if p.name != "C"]
    new.nprocesses = len(new.processes)
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, old)]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1[:12], 4) + batches(2, dpu2, 2)]
    events += [(CONFIG_CHANNEL, new)]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1[12:], 4, generation=new.generation, first_seq=3)]
    out = tmp_path / "run.mcap"
    export(load_run(write_log(tmp_path / "run.lcm", events)), out)
    assert {channel.topic for channel, _, _ in _timing(out)} == {"/timing/1/A", "/timing/1/B", "/timing/2/C"}


def _status(host: str = "lab-1", lockouts: int = 0) -> bytes:
    """analysis_synth's heartbeat of DPU 3 from `host`, naming `lockouts` lockouts, encoded."""
    heartbeat = status(3, [(k, -1, 40 + k) for k in range(lockouts)])
    heartbeat.host = host
    return bytes(heartbeat.encode())


def test_a_refused_message_does_not_read_the_log_as_its_strings() -> None:
    """A message the bulk read refuses has no places for its strings: reading them anyway
    took the whole buffer as each string (GBs of a long log)."""
    refused, good = b"not a status" * 4, _status()
    buf = np.frombuffer(refused + b"\0" * (64 << 20) + good, dtype=np.uint8)
    starts, lengths = np.array([0, len(buf) - len(good)]), np.array([len(refused), len(good)])
    tracemalloc.start()
    try:
        rows = list(to_json_many(skelmsg.status_t, buf, starts, lengths))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert rows == [None, to_json(skelmsg.status_t.decode(good))]
    assert peak < 16 << 20, f"{peak >> 20} MiB traced for 2 statuses"


@pytest.mark.parametrize("moved", [False, True])
def test_a_records_topic_is_its_dpu_and_process_pair_whether_or_not_a_process_moved(moved: bool) -> None:
    """_pairs looks processes up in a table when each ran on one DPU, and sorts the pairs
    when one moved (a live switch): the same pairs and indices as sorting them every time."""
    rng = np.random.default_rng(7)
    process = rng.integers(-5, 40, 10_000).astype(np.int16)
    dpu = (process % 7 - 3).astype(np.int16)
    if moved:
        dpu[:50] += 1
    keys, index = _pairs(dpu, process)
    expected = np.unique((dpu.astype(np.int64) + 32768) * 65536 + process.astype(np.int64) + 32768,
                         return_inverse=True)  # fmt: skip
    assert np.array_equal(keys, expected[0]) and np.array_equal(index, expected[1].reshape(-1))
