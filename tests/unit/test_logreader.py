"""logreader.py (the LCM log format, damage), flatdecode.py and records.py (timing_t fast path)."""

from __future__ import annotations

import itertools
import json
import mmap
from pathlib import Path

import lcm
import numpy as np
import pytest
from analysis_synth import RUN_ID, batches, small_config, small_run, status, write_log
from conftest import mapped_kib

import skelmsg
from skeleton.analysis.measure.faults import lockouts_from_status
from skeleton.analysis.measure.run import analyze_log
from skeleton.analysis.read import flatdecode, logreader, parallel
from skeleton.analysis.read.coltable import ColumnTable
from skeleton.analysis.read.flatdecode import FlatLayout
from skeleton.analysis.read.lcmjson import to_json, to_json_many
from skeleton.analysis.read.logreader import HEADER_BYTES, SYNC_BYTES, encode_events, read_bytes, read_log
from skeleton.analysis.read.messages import decode_timed, int_columns, read_messages
from skeleton.analysis.read.records import (
    DURATIONS,
    INPUT_DTYPE,
    RECORD_DTYPE,
    TIMING,
    decode_run,
    impossible,
    input_starts,
    load_records,
    robust_span,
    run_ids,
)
from skelmsg.contract import CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL


@pytest.fixture(params=["walk", "scan"], autouse=True)
def walk_mode(request: pytest.FixtureRequest, monkeypatch: pytest.MonkeyPatch) -> str:
    """Every reader test runs twice: walking event by event, and with the sync-word scan
    (which only big logs of small events use by default) in many small chunks, and the
    columns decoded, on threads as big logs are (parallel.py). Both read the file in
    chunks of a few pages, so that events and damage lie across chunks' ends as in a big log."""
    monkeypatch.setattr(logreader, "GIVE_BACK_BYTES", 4099)
    if request.param == "scan":
        monkeypatch.setattr(logreader, "SCAN_MIN_FILE_BYTES", 0)
        monkeypatch.setattr(logreader, "SCAN_BELOW_MEAN_BYTES", 1 << 30)
        monkeypatch.setattr(logreader, "_PROBE_EVENTS", 1)
        monkeypatch.setattr(logreader, "SYNC_CHUNK_BYTES", 61)  # sync words across chunk ends too
        monkeypatch.setattr(parallel, "WORTH_BYTES", 0)
    return str(request.param)


def _reference(path: Path) -> list[tuple[int, int, str, bytes]]:
    return [(e.eventnum, e.timestamp, e.channel, e.data) for e in lcm.EventLog(str(path))]


def _sample_log(path: Path) -> Path:
    dpu1, dpu2 = small_run()
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config())]
    for t in batches(1, dpu1, 3) + batches(2, dpu2, 2):
        events.append((TIMING_CHANNEL, t))
        events.append(("SKEL_BUF_a_out", bytes(range(7))))
        events.append((STATUS_CHANNEL, status(t.dpu, [])))
    events.append(("X", b""))  # an empty message is a valid event
    return write_log(path, events)


def _garbage(n: int) -> bytes:
    data = np.random.default_rng(7).integers(0, 256, n, dtype=np.uint8).tobytes()
    assert SYNC_BYTES not in data
    return data


def test_events_equal_lcm_eventlog(tmp_path: Path) -> None:
    path = _sample_log(tmp_path / "a.lcm")
    log = read_log(path)
    assert [tuple(e) for e in log.events] == _reference(path)
    assert log.integrity.events == len(_reference(path))
    assert log.integrity.corrupt_ranges == [] and not log.integrity.truncated_tail
    assert log.channel_names("SKEL_") == ["SKEL_BUF_a_out", CONFIG_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL]
    timing = log.messages(TIMING_CHANNEL)
    assert [bytes(d) for _, d in timing] == [e[3] for e in _reference(path) if e[2] == TIMING_CHANNEL]
    assert log.messages("nope") == []


def test_garbage_in_the_middle_is_reported_and_skipped(tmp_path: Path) -> None:
    path = _sample_log(tmp_path / "a.lcm")
    good = _reference(path)
    offsets = read_log(path).offset.tolist()
    raw = path.read_bytes()
    cut = offsets[10]
    junk = _garbage(333)
    damaged = tmp_path / "damaged.lcm"
    damaged.write_bytes(raw[:cut] + junk + raw[cut:])
    log = read_log(damaged)
    assert [tuple(e) for e in log.events] == good  # nothing lost before or after
    assert log.integrity.corrupt_ranges == [(cut, cut + len(junk))]
    assert not log.integrity.truncated_tail
    # lcm.EventLog stops at the damage (the reason we have our own reader)
    assert len(_reference(damaged)) < len(good)


def test_overwritten_header_loses_exactly_that_event(tmp_path: Path) -> None:
    path = _sample_log(tmp_path / "a.lcm")
    good = _reference(path)
    offsets = read_log(path).offset.tolist()
    raw = bytearray(path.read_bytes())
    raw[offsets[5] : offsets[5] + 20] = _garbage(20)
    damaged = tmp_path / "damaged.lcm"
    damaged.write_bytes(bytes(raw))
    log = read_log(damaged)
    assert [tuple(e) for e in log.events] == good[:5] + good[6:]
    assert log.integrity.corrupt_ranges == [(offsets[5], offsets[6])]


@pytest.mark.parametrize("keep", [1, 3, 20, 27, 40])
def test_truncated_tail(tmp_path: Path, keep: int) -> None:
    path = _sample_log(tmp_path / "a.lcm")
    good = _reference(path)
    offsets = read_log(path).offset.tolist()
    raw = path.read_bytes()
    last = offsets[-2]  # cut inside the second-to-last event (the last one is empty)
    cut = tmp_path / "cut.lcm"
    cut.write_bytes(raw[: last + keep])
    log = read_log(cut)
    assert [tuple(e) for e in log.events] == good[:-2]
    assert log.integrity.corrupt_ranges == [(last, last + keep)]
    assert log.integrity.truncated_tail


def test_garbage_file_and_empty_file(tmp_path: Path) -> None:
    junk = tmp_path / "junk.lcm"
    junk.write_bytes(_garbage(1000))
    log = read_log(junk)
    assert len(log) == 0 and log.integrity.corrupt_ranges == [(0, 1000)]
    assert not log.integrity.truncated_tail
    empty = tmp_path / "empty.lcm"
    empty.write_bytes(b"")
    assert len(read_log(empty)) == 0 and read_log(empty).integrity.corrupt_ranges == []


def test_flat_layout_is_derived_from_the_generated_class() -> None:
    assert TIMING.fingerprint == skelmsg.timing_t._get_packed_fingerprint()
    assert set(TIMING.arrays) == {
        n for n, d in zip(skelmsg.timing_t.__slots__, skelmsg.timing_t.__dimensions__, strict=True) if d
    }
    with pytest.raises(TypeError):
        FlatLayout.of(skelmsg.config_t)  # nested structs and strings are not flat
    with pytest.raises(TypeError):
        FlatLayout.of(skelmsg.config_t, skipping=True)  # its links hold strings: no fixed size to pass over


@pytest.mark.parametrize("equal", [False, True])  # True: every batch as long, its arrays read as rows
@pytest.mark.parametrize("gather_bytes", [flatdecode._GATHER_BYTES, 1])  # 1: a row gathered at a time
def test_fast_timing_decode_equals_generated_decoder(gather_bytes: int, equal: bool,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(flatdecode, "_GATHER_BYTES", gather_bytes)
    rng = np.random.default_rng(3)
    msgs = []
    for seq in range(4):
        t = skelmsg.timing_t()
        n, m = (5, 7) if equal else (int(rng.integers(0, 9)), int(rng.integers(0, 20)))
        t.dpu, t.run_id, t.generation, t.batch_seq, t.n, t.ninputs = 5, RUN_ID, 2, seq, n, m if n else 0
        for name, kind, dims in zip(t.__slots__, t.__typenames__, t.__dimensions__, strict=True):
            if dims is None:
                continue
            bits = {"int8_t": 7, "int16_t": 15, "int32_t": 31, "int64_t": 63}[kind]
            size = n if dims == ["n"] else t.ninputs
            setattr(t, name, rng.integers(-(2**bits), 2**bits - 1, size).tolist())
        t.in_record = rng.integers(0, max(n, 1), t.ninputs).tolist()
        msgs.append(t.encode())
    run = decode_run(msgs, RUN_ID)
    ref = [skelmsg.timing_t.decode(d) for d in msgs]
    for name in ("process", "cycle", "minor", "release_ns", "start_ns", "comm_in_ns", "blocked_ns",
                 "asked_ns", "compute_ns", "comm_out_ns", "idle_ns", "slack_ns", "event_ns", "event_queued",
                 "event_dropped", "flags"):  # fmt: skip
        assert run.records[name].tolist() == [v for r in ref for v in getattr(r, name)], name
    pairs = {"buffer": "in_buffer", "seq": "in_seq", "new": "in_new", "dropped": "in_dropped",
             "received": "in_received", "sent_ns": "in_sent_ns", "recv_ns": "in_recv_ns"}  # fmt: skip
    base = np.cumsum([0] + [r.n for r in ref])
    # Each input as the wire lists it, with its record's index in the run; the table holds
    # them in their records' order (a stable sort: a record's own keep the wire's order).
    wire = [(base[i] + r.in_record[k], *(getattr(r, theirs)[k] for theirs in pairs.values()))
            for i, r in enumerate(ref) for k in range(r.ninputs)]  # fmt: skip
    assert any(a[0] > b[0] for a, b in itertools.pairwise(wire))  # the wire's order is not theirs
    want = sorted(wire, key=lambda row: row[0])
    assert run.inputs["record"].tolist() == [row[0] for row in want]
    for column, ours in enumerate(pairs, start=1):
        assert run.inputs[ours].tolist() == [row[column] for row in want], ours


def test_statuses_bulk_decoded_give_what_the_generated_decoder_does(tmp_path: Path) -> None:
    """status_t's integers read in numpy, its strings and lockouts passed over: the columns,
    the lockouts and the malformed count all as from an object a status."""
    rng = np.random.default_rng(5)
    sent = []
    named: dict[int, list[tuple[int, ...]]] = {0: [], 1: [], 2: []}
    for k in range(40):
        dpu = k % 3
        if k % 7 == 0:
            named[dpu].append((k, -1, k))  # named again in each of the DPU's heartbeats after
        s = status(dpu, named[dpu], run_id=1 + (k >= 30))  # run 2: the same lockouts, in another run
        s.host = "h" * int(rng.integers(0, 30)) + "é" * (k % 2)  # the strings vary the fields' places
        s.reject_reason, s.run_owner = "x" * int(rng.integers(0, 90)), f"HOST pid {k}"
        s.pid, s.mono_ns, s.utc_ns = 100 + k, 10**9 + k, 2 * 10**18 + k
        s.ping_seq, s.run_end_utc_ns = 7 * k, 3 * 10**18 + k  # after the lockouts and a string
        sent.append(s.encode())
    negative = bytearray(status(1, []).encode())  # nlockouts < 0: the generated decoder reads none
    at = 8 + 2 + (4 + 2) + 29 + (4 + 1) + 133  # fingerprint, dpu, host "h", 29 bytes, reason "", 133 bytes
    negative[at : at + 2] = (-2).to_bytes(2, "big", signed=True)
    endless = bytearray(sent[8])
    endless[10:14] = b"\xff" * 4  # the host's byte count: 2^32 - 1
    trailing = sent[9] + b"\x01\x02"  # bytes after the message: read by neither decoder
    # sent[5] cut into run_end_utc_ns: a cut only into the last string's nul is read by both
    damaged = [sent[5][:-6], sent[6][:30], b"\x00" * 12, bytes(endless), bytes(negative), trailing]
    path = write_log(tmp_path / "s.lcm", [(STATUS_CHANNEL, m) for m in sent + damaged])
    fields = ("dpu", "pid", "run_id", "state", "mono_ns", "utc_ns", "nlockouts", "ping_seq", "run_end_utc_ns")

    messages = read_messages(read_log(path), set())
    bulk = messages.status_columns(*fields)
    log, malformed = read_log(path), {}  # each decoded alone by the generated decoder
    whole = decode_timed(log, STATUS_CHANNEL, skelmsg.status_t.decode, malformed)
    statuses = [s for _, s in whole]
    assert len(statuses) == len(bulk.heard_us) == len(sent) + 2  # 2 of the 6 damaged decode
    assert bulk.heard_us.tolist() == [t for t, _ in whole]
    for name, column in zip(fields, int_columns(statuses, *fields), strict=True):
        assert bulk.fields[name].tolist() == column.tolist(), name
    assert bulk.fields["nlockouts"].tolist()[-2:] == [-2, 1]
    assert messages.malformed == malformed == {STATUS_CHANNEL: 4}
    # Their JSON (skel export) read in bulk too: as the generated decoder's object, as JSON.
    idx = log.indices(STATUS_CHANNEL)
    made = to_json_many(skelmsg.status_t, log.buf, log.data_offset[idx], log.data_len[idx], log.release)
    rows = [json.dumps(r) for r in made if r is not None]
    assert rows == [json.dumps(to_json(s)) for s in statuses]
    # A heartbeat repeating its DPU's last lockouts (in the same run) is not decoded whole.
    first_named = [(s.dpu, s.run_id, len(s.lockouts)) for s in bulk.locking]
    assert first_named == [(0, 1, 1), (1, 1, 1), (2, 1, 1), (0, 1, 2), (1, 1, 2),  # run 1
                           (0, 2, 2), (1, 2, 2), (2, 2, 1), (2, 2, 2),  # run 2
                           (0, 1, 1)]  # not the last DPU 0 named: sent[9] again
    for run_id in (1, 2):
        assert lockouts_from_status(bulk.locking, run_id) == lockouts_from_status(statuses, run_id)


def test_malformed_timing_messages_are_counted_not_fatal() -> None:
    good = batches(1, small_run()[0], 4)
    data = good[0].encode()
    bad_len = bytearray(data)
    bad_len[8 + 26 : 8 + 30] = (-5).to_bytes(4, "big", signed=True)  # n < 0
    bad_record = good[1]
    bad_record.in_record = [99] * bad_record.ninputs  # points outside its batch
    msgs = [data[:50], b"\x00" * 40, bytes(bad_len), bad_record.encode(), *(t.encode() for t in good[2:])]
    run = decode_run(msgs, RUN_ID)
    assert run.malformed == 4 and run.batches == len(good) - 2
    assert decode_run([data[:-1], data], RUN_ID).malformed == 1  # one byte short


def test_run_selection_default_is_last_run(tmp_path: Path) -> None:
    dpu1, _ = small_run()
    events = [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 5, run_id=9)]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 5, run_id=RUN_ID)]
    events += [(TIMING_CHANNEL, b"garbage")]
    log = read_log(write_log(tmp_path / "runs.lcm", events))
    assert run_ids(log) == [9, RUN_ID]
    assert load_records(log).run_id == RUN_ID
    first = load_records(log, 9)
    assert first.run_id == 9 and len(first.records) == 20 and first.malformed == 1


def test_encoded_events_read_back_by_both_readers(tmp_path: Path) -> None:
    path = _sample_log(tmp_path / "a.lcm")
    events = [(t, c, d) for _, t, c, d in _reference(path)]
    data = encode_events(events)
    assert data == path.read_bytes()  # lcm-logger's format, byte for byte (events numbered from 0)
    log = read_bytes(data)
    assert [tuple(e) for e in log.events] == _reference(path)
    assert log.integrity.events == len(events) and not log.integrity.damaged
    assert len(read_bytes(b"")) == 0


def _timing_message(seq: int, n: int, m: int, rng: np.random.Generator) -> bytes:
    t = skelmsg.timing_t()
    t.dpu, t.run_id, t.generation, t.batch_seq, t.n, t.ninputs = 5, RUN_ID, 2, seq, n, m
    for name, dims in zip(t.__slots__, t.__dimensions__, strict=True):
        if dims is not None:
            low = 0 if name in DURATIONS else -100  # a negative duration is impossible: left out
            setattr(t, name, rng.integers(low, 100, n if dims == ["n"] else m).tolist())
    t.in_record = rng.integers(0, max(n, 1), m).tolist()
    return t.encode()


@pytest.mark.parametrize(
    "shapes",
    [
        [(64, 100), (64, 150), (64, 3)],  # padded rows of unequal lengths
        [(64, 100)] * 7 + [(64, 3)],  # the last message is padded past the buffer's end
        [(2, 1), (3, 2), (2, 5000), (1, 1)],  # one long outlier: decoded by groups of equal length
        [(8, 8)] * 5,  # all equal: no mask
        [(0, 0), (4, 0), (0, 0)],  # empty arrays
    ],
)
def test_bulk_decode_of_every_length_pattern(shapes: list[tuple[int, int]]) -> None:
    rng = np.random.default_rng(11)
    msgs = [_timing_message(seq, n, m if n else 0, rng) for seq, (n, m) in enumerate(shapes)]
    run = decode_run(msgs, RUN_ID)
    ref = [skelmsg.timing_t.decode(d) for d in msgs]
    assert run.malformed == 0 and run.batches == len(msgs)
    assert run.records["slack_ns"].tolist() == [v for r in ref for v in r.slack_ns]
    assert run.records["flags"].tolist() == [v for r in ref for v in r.flags]
    _, inputs = _structured(msgs, RUN_ID)
    for name in ("record", "recv_ns", "buffer", "new"):
        assert run.inputs[name].tolist() == inputs[name].tolist(), name


def test_sync_words_inside_data_are_not_events(tmp_path: Path, walk_mode: str) -> None:
    fake = SYNC_BYTES + (7).to_bytes(8, "big") * 2 + (3).to_bytes(4, "big") + (0).to_bytes(4, "big") + b"ABC"
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, small_config())]
    for i in range(30):
        events.append(("SKEL_BUF_a_out", fake * (i % 3) + bytes(i)))  # whole fake events in the data
        events.append((STATUS_CHANNEL, status(1, [])))
    path = write_log(tmp_path / "fake.lcm", events)
    log = read_log(path)
    assert [tuple(e) for e in log.events] == _reference(path)
    assert not log.integrity.damaged
    if walk_mode == "scan":
        assert logreader._many_small_events(memoryview(path.read_bytes()), path.stat().st_size)


def _structured(msgs: list[bytes], run_id: int) -> tuple[np.ndarray, np.ndarray]:
    """The records and inputs as the structured arrays they were before columns, built
    with the generated decoder message by message: first good copy of each batch; the inputs
    in their records' order (a stable sort of the wire's)."""
    seen: set[tuple[int, int]] = set()
    recs: list[tuple[int, ...]] = []
    ins: list[tuple[int, ...]] = []
    for data in msgs:
        try:
            t = skelmsg.timing_t.decode(data)
        except Exception:
            continue
        if t.run_id != run_id or (t.dpu, t.batch_seq) in seen or any(not 0 <= r < t.n for r in t.in_record):
            continue
        seen.add((t.dpu, t.batch_seq))
        base = len(recs)
        for i in range(t.n):
            recs.append((t.dpu, t.process[i], t.generation, t.batch_seq, t.cycle[i], t.minor[i],
                         t.release_ns[i], t.sched_ns[i], t.start_ns[i], t.comm_in_ns[i], t.blocked_ns[i],
                         t.asked_ns[i],
                         t.compute_ns[i], t.comm_out_ns[i], t.idle_ns[i], t.slack_ns[i], t.stall_ns[i],
                         t.debt_ns[i], t.preemptions[i], t.preempted_ns[i], t.event_ns[i], t.event_queued[i],
                         t.event_dropped[i], t.flags[i]))  # fmt: skip
        for j, r in enumerate(t.in_record):
            ins.append((base + r, t.dpu, t.process[r], t.cycle[r], t.in_buffer[j], t.in_seq[j], t.in_new[j],
                        t.in_dropped[j], t.in_received[j], t.in_sent_ns[j], t.in_recv_ns[j]))  # fmt: skip
    ins.sort(key=lambda row: row[0])
    return np.array(recs, dtype=RECORD_DTYPE), np.array(ins, dtype=INPUT_DTYPE)


def test_a_derived_column_is_made_on_first_read_once_for_every_table_indexed_from_it() -> None:
    made: list[int] = []
    values = np.arange(10, dtype=np.int64)

    def doubled() -> np.ndarray:
        made.append(1)
        return values * 2

    dtype = np.dtype([("a", "i8"), ("b", "i4")])
    table = ColumnTable.of({"a": values}, dtype, derive={"b": doubled})
    even, middle = table[values % 2 == 0], table[2:5]
    assert np.array_equal(even["a"], values[::2]) and not made  # another column: b not made
    assert np.array_equal(even["b"], values[::2] * 2) and np.array_equal(middle["b"], [4, 6, 8])
    assert np.array_equal(table[[9, 0]]["b"], [18, 0]) and table["b"].dtype == np.int32
    assert np.array_equal(np.asarray(table)["b"], values * 2) and len(made) == 1
    with pytest.raises(ValueError):
        ColumnTable.of({"a": values, "b": values}, dtype, derive={"b": doubled})


@pytest.mark.parametrize("chunk_bytes", [flatdecode.CHUNK_BYTES, 700])  # 700: a few messages a chunk
def test_run_records_equal_the_structured_arrays_field_by_field(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, chunk_bytes: int
) -> None:
    monkeypatch.setattr(flatdecode, "CHUNK_BYTES", chunk_bytes)
    rng = np.random.default_rng(5)
    msgs = [_timing_message(seq, n, m if n else 0, rng) for seq, (n, m) in
            enumerate([(64, 100), (64, 150), (3, 2), (0, 0), (64, 3), (5, 5000), (1, 1)])]  # fmt: skip
    bad = skelmsg.timing_t.decode(msgs[2])
    bad.in_record = [7] * bad.ninputs  # outside its batch: malformed, dropped
    msgs[2] = bad.encode()
    msgs += [msgs[1], msgs[4][:-3], b"junk"]  # a duplicate, a cut one, garbage
    log = read_log(write_log(tmp_path / "t.lcm", [(TIMING_CHANNEL, m) for m in msgs]))
    for run in (load_records(log), decode_run(msgs, RUN_ID)):
        want_recs, want_ins = _structured(msgs, RUN_ID)
        assert run.malformed == 3 and run.duplicates == 1 and len(run.records) == len(want_recs) > 100
        for got, want in ((run.records, want_recs), (run.inputs, want_ins)):
            assert got.dtype == want.dtype and len(got) == len(want)
            for name in want.dtype.names:
                assert got[name].dtype == want[name].dtype, name
                assert np.array_equal(got[name], want[name]), name
            as_array = np.asarray(got)
            assert as_array.dtype == want.dtype and np.array_equal(as_array, want)
            # What the callers do with a table behaves as it did on the structured array.
            mask = want["process"] % 3 == 0
            assert np.array_equal(np.asarray(got[mask]), want[mask])
            idx = np.flatnonzero(mask)[::-1]
            assert np.array_equal(np.asarray(got[idx][2:9]), want[idx][2:9])
            assert np.array_equal(np.asarray(got[mask][idx[: mask.sum()] % max(1, mask.sum())]),
                                  want[mask][idx[: mask.sum()] % max(1, mask.sum())])  # fmt: skip
            assert got[-1] == want[-1] and got[3]["cycle"] == want[3]["cycle"]
            assert [r["process"] for r in got][:50] == [r["process"] for r in want][:50]
            copy = got[mask].copy()
            copy["cycle"] = -1
            assert np.array_equal(got["cycle"], want["cycle"]) and (copy["cycle"] == -1).all()
            assert len(got[np.zeros(len(want), dtype=bool)]) == 0 and len(got[[]]) == 0
            with pytest.raises(IndexError):
                got[np.array([len(want)])]
            with pytest.raises(IndexError):
                got[np.ones(len(want) + 1, dtype=bool)]


def test_sync_word_scan_finds_every_one_across_chunk_ends(walk_mode: str) -> None:
    """The scan is only a short cut (a missed sync word falls back to walking), so it is
    checked on its own: every sync word, also one cut by a chunk's end, on every thread."""
    buf = np.frombuffer(_garbage(5000), dtype=np.uint8).copy()
    where = [0, 59, 120, 182, 244, 1000, 4996]  # cut by the ends of 61-byte chunks ("scan" mode)
    for at in where:
        buf[at : at + 4] = np.frombuffer(SYNC_BYTES, dtype=np.uint8)
    expected = [i for i in range(len(buf) - HEADER_BYTES + 1) if bytes(buf[i : i + 4]) == SYNC_BYTES]
    found, _ = logreader._sync_words(buf, len(buf), logreader._Channels(), lambda start, end: None)
    assert found.tolist() == expected and len(expected) >= 6


def test_opening_a_log_holds_about_a_chunk_of_it(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """The walk gives each chunk's pages back before reading on: opening a log of 10^7
    records (2.3 GB) held all of it at the end of the walk."""
    monkeypatch.setattr(logreader, "GIVE_BACK_BYTES", 1 << 20)
    monkeypatch.setattr(logreader, "SYNC_CHUNK_BYTES", 1 << 20)
    # The probe of the first events reads pages ahead of the walk (up to _PROBE_EVENTS
    # headers, a few MB of a big log but here all of the few events).
    monkeypatch.setattr(logreader, "_PROBE_EVENTS", 4)
    dpu1, dpu2 = small_run(cycles=20000)
    events = [(CONFIG_CHANNEL, small_config())] + [(TIMING_CHANNEL, t) for t in
                                                    batches(1, dpu1, 20) + batches(2, dpu2, 20)]  # fmt: skip
    path = write_log(tmp_path / "run.lcm", events)
    size_kib = path.stat().st_size // 1024
    held: list[int] = []
    give_back = logreader._give_back

    def watched(mapping: mmap.mmap | None, size: int, start: int, end: int | None) -> None:
        held.append(mapped_kib(path))
        give_back(mapping, size, start, end)

    monkeypatch.setattr(logreader, "_give_back", watched)
    log = read_log(path)
    assert len(log) == len(events) and size_kib > 8 * 1024
    assert len(held) > 8 and max(held) <= size_kib // 4


def test_the_analysis_gives_back_the_pages_of_the_log_it_read(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Decoded a chunk at a time, each chunk's pages given back: a log of 10^7 records
    (2.3 GB) no longer stays resident beside its columns. The pages are read in full
    first (the walk reads them all), so without the giving back they would all count."""
    # Chunks of 1 MiB: a boundary's page read again maps the 64 KiB around it (fault-around)
    monkeypatch.setattr(flatdecode, "CHUNK_BYTES", 1 << 20)
    # The scan in 64 KiB steps, not walk_mode's 61 bytes: 150,000 steps over this log took 25 s of
    # CI for what test_sync_word_scan_finds_every_one_across_chunk_ends checks on a small one.
    monkeypatch.setattr(logreader, "SYNC_CHUNK_BYTES", 1 << 16)
    dpu1, dpu2 = small_run(cycles=20000)
    events = [(CONFIG_CHANNEL, small_config())] + [(TIMING_CHANNEL, t) for t in
                                                    batches(1, dpu1, 20) + batches(2, dpu2, 20)]  # fmt: skip
    path = write_log(tmp_path / "run.lcm", events)
    size_kib = path.stat().st_size // 1024
    assert size_kib > 8 * 1024
    log = read_log(path)
    assert mapped_kib(path) <= size_kib // 8  # the walk's pages given back
    for analyse in (load_records, analyze_log):  # the decode alone, then the whole analysis
        log.buf.sum()  # every page read (as a pass over it does): all resident now
        assert mapped_kib(path) >= size_kib * 3 // 4
        run = analyse(log)
        assert mapped_kib(path) <= size_kib // 8, analyse.__name__
    assert len(run.recorded.records) == len(dpu1) + len(dpu2)


def test_a_records_inputs_are_one_run_of_rows_and_out_of_order_inputs_are_refused() -> None:
    inputs = ColumnTable.of({name: np.zeros(4, dtype=INPUT_DTYPE[name]) for name in INPUT_DTYPE.names or ()},
                            INPUT_DTYPE)  # fmt: skip
    inputs["record"] = [0, 0, 2, 3]
    starts = input_starts(inputs, 5)
    assert starts.tolist() == [0, 2, 2, 3, 4, 4]
    inputs["record"] = [0, 2, 0, 3]
    with pytest.raises(ValueError, match="records' order"):
        input_starts(inputs, 5)


@pytest.mark.parametrize("name", ["start_ns", "sched_ns", "slack_ns", "compute_ns", "idle_ns", "event_ns"])
def test_a_time_a_flipped_bit_put_far_from_its_release_is_impossible(name: str) -> None:
    dpu1, _ = small_run()
    records = decode_run([t.encode() for t in batches(1, dpu1, 4)], RUN_ID).records
    records["event_ns"][:] = records["start_ns"] - 1000  # event cycles (-1 in a cycle of no event)
    assert not impossible(records, 0).any()
    records[name][5] ^= 1 << 60  # what one flipped bit in the log's bytes does
    records[name][7] ^= np.int64(-(2**63))  # the sign bit
    assert np.flatnonzero(impossible(records, 0)).tolist() == [5, 7]


def test_a_negative_duration_is_impossible() -> None:
    """A DPU measures none; a duration's bits inverted make one (-3 ms, within the bound)."""
    dpu1, _ = small_run()
    records = decode_run([t.encode() for t in batches(1, dpu1, 4)], RUN_ID).records
    records["idle_ns"][13] = ~records["idle_ns"][13]
    assert np.flatnonzero(impossible(records, 0)).tolist() == [13]


def test_a_run_whose_every_cycle_lags_ten_minutes_is_possible_and_a_flip_in_it_is_not() -> None:
    """A log begun long after its run did (an overloaded DPU's lag, an event's wait): what most
    records show of a quantity widens its bound; one damaged record does not."""
    dpu1, _ = small_run()
    records = decode_run([t.encode() for t in batches(1, dpu1, 4)], RUN_ID).records
    records["start_ns"][:] += 600 * 10**9
    records["event_ns"][:3] = records["start_ns"][:3] - 300 * 10**9  # event cycles, waited long
    assert not impossible(records, 0).any()
    records["start_ns"][9] ^= 1 << 60
    assert np.flatnonzero(impossible(records, 0)).tolist() == [9]


def test_a_damaged_time_stamp_does_not_widen_the_span() -> None:
    times = np.arange(10_000, dtype=np.int64) * 1000
    times[17] ^= np.int64(-(2**63))
    times[18] ^= 1 << 61
    assert robust_span(times) < 10_000_000 and robust_span(times[:0]) == 0
