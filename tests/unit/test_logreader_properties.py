"""The log reader on any bytes (Hypothesis): arbitrary bytes, and a real small log truncated
or with bits flipped. The reader never raises; every event whose bytes are untouched is
recovered, with its channel and data; the analysis of what is left gives a report or the one
LogError line for the user. `make fuzz` runs thousands of examples."""

from __future__ import annotations

import pytest
from analysis_synth import RUN_ID, batches, small_config, small_run, write_log
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from skeleton.analysis.measure.run import analyze_log
from skeleton.analysis.read.logreader import read_bytes
from skeleton.analysis.read.messages import LogError
from skelmsg.contract import CONFIG_CHANNEL, TIMING_CHANNEL

pytestmark = pytest.mark.filterwarnings("ignore::RuntimeWarning")  # numpy on empty windows


@pytest.fixture(scope="module")
def real(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    dpu1, dpu2 = small_run()
    path = tmp_path_factory.mktemp("log") / "run.lcm"
    write_log(path, [(CONFIG_CHANNEL, small_config())] + [
        (TIMING_CHANNEL, t) for t in batches(1, dpu1, 4) + batches(2, dpu2, 2)])
    return path.read_bytes()


def _spans(data: bytes) -> list[tuple[int, int, str, bytes]]:
    """(first byte, end, channel, data) of each event of an undamaged log."""
    log = read_bytes(data)
    return [(int(log.offset[i]), int(log.data_offset[i] + log.data_len[i]),
             log.channels[int(log.channel_id[i])], bytes(log.data(i))) for i in range(len(log))]


def _analyse(data: bytes) -> None:
    try:
        analyze_log(read_bytes(data), RUN_ID)
    except LogError as error:
        assert "\n" not in str(error)


@given(data=st.binary(max_size=2000))
def test_any_bytes_read_without_an_exception(data: bytes) -> None:
    log = read_bytes(data)
    assert len(log) >= 0 and log.integrity.events == len(log)
    _analyse(data)


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(cut=st.integers(0, 10**6))
def test_a_truncated_log_keeps_every_whole_event(real: bytes, cut: int) -> None:
    cut %= len(real) + 1
    whole = [(c, d) for start, end, c, d in _spans(real) if end <= cut]
    log = read_bytes(real[:cut])
    got = [(log.channels[int(log.channel_id[i])], bytes(log.data(i))) for i in range(len(log))]
    assert got == whole
    _analyse(real[:cut])


@settings(suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(flips=st.lists(st.integers(0, 10**7), min_size=1, max_size=8))
def test_flipped_bits_lose_only_the_events_they_touch(real: bytes, flips: list[int]) -> None:
    damaged = bytearray(real)
    at = sorted({f % (len(real) * 8) for f in flips})
    for bit in at:
        damaged[bit // 8] ^= 1 << (bit % 8)
    touched = {bit // 8 for bit in at}
    untouched = [(c, d) for start, end, c, d in _spans(real) if not any(start <= b < end for b in touched)]
    log = read_bytes(bytes(damaged))
    got = [(log.channels[int(log.channel_id[i])], bytes(log.data(i))) for i in range(len(log))]
    for event in untouched:
        assert event in got, (at, event[0])
    _analyse(bytes(damaged))


def test_an_event_between_two_damaged_sync_words_is_kept(real: bytes) -> None:
    """Found by the property above: with the first event's sync word damaged the reader
    looks for the next, and the second event, whole, was refused because the sync word
    after it was damaged too."""
    spans = _spans(real)
    damaged = bytearray(real)
    damaged[spans[0][0]] ^= 1
    damaged[spans[2][0]] ^= 1
    log = read_bytes(bytes(damaged))
    got = [(log.channels[int(log.channel_id[i])], bytes(log.data(i))) for i in range(len(log))]
    assert (spans[1][2], spans[1][3]) in got
    assert [c for c, _ in got] == [c for _, _, c, _ in spans[1:2] + spans[3:]]
