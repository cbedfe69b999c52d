"""export_mcap.py, mcapbulk.py, mcapsource.py and lcmjson.py on a real run: `skel export`,
read back with the mcap package (timing messages decoded by Foxglove's own ROS 2 CDR
decoder, mcap-ros2-support) and compared with the LCM log record by record."""

from __future__ import annotations

import json
import struct
import subprocess
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pyarrow.parquet as pq
import pytest
import zstandard
from conftest import mapped_kib, short_servo_run, skel
from mcap.reader import make_reader
from mcap.writer import Writer
from mcap_ros2.decoder import DecoderFactory
from unit.test_export_mcap import _status, _timing

import skelmsg
from skeleton.analysis.measure.run import analyze_log, load_run
from skeleton.analysis.read.lcmjson import schema_of, to_json, to_json_many
from skeleton.analysis.read.logreader import encode_events, read_bytes, read_log
from skeleton.analysis.read.mcapsource import read_as_log
from skeleton.analysis.read.records import load_records
from skeleton.analysis.views import mcapbulk, outfile
from skeleton.analysis.views.export_mcap import MESSAGE_CHANNELS, export
from skelmsg.contract import COMMAND_CHANNEL, CONFIG_CHANNEL, REPORT_CHANNEL, STATUS_CHANNEL, TIMING_CHANNEL

RECORD_FIELDS = ["dpu", "process", "generation", "batch_seq", "cycle", "minor", "release_ns",
                 "start_ns", "comm_in_ns", "blocked_ns", "asked_ns", "compute_ns", "comm_out_ns", "idle_ns",
                 "slack_ns", "flags"]  # fmt: skip
INPUT_FIELDS = ["buffer", "seq", "new", "dropped", "received", "sent_ns", "recv_ns"]


@pytest.fixture(scope="module")
def servo_run(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Path]:
    """One short real SERVO run (sanitizer DPUs) and its export, shared by this module."""
    out = tmp_path_factory.mktemp("servo") / "run"
    short_servo_run(out)
    exported = skel("export", str(out / "run.lcm"), str(out / "run.mcap"))
    assert exported.returncode == 0, exported.stderr
    assert "timing records" in exported.stdout
    yield out


def _messages(path: Path) -> dict[str, list[tuple[Any, Any]]]:
    """topic -> [(channel, message)] in file order."""
    out: dict[str, list[tuple[Any, Any]]] = defaultdict(list)
    with open(path, "rb") as f:
        for _, channel, message in make_reader(f).iter_messages(log_time_order=False):
            out[channel.topic].append((channel, message))
    return out


def test_every_timing_record_and_input_matches_the_log(servo_run: Path) -> None:
    log = read_log(servo_run / "run.lcm")
    run = load_records(log)
    config = skelmsg.config_t.decode(bytes(log.messages(CONFIG_CHANNEL)[-1][1]))
    names = {p.id: p.name for p in config.processes}
    buffers = {str(b.id): b.name for b in config.buffers}
    by_key = {}
    for channel, message, decoded in _timing(servo_run / "run.mcap"):
        body = {k: getattr(decoded, k) for k in decoded.__slots__}
        body["inputs"] = [{k: getattr(i, k) for k in i.__slots__} for i in decoded.inputs]
        assert channel.topic == f"/timing/{body['dpu']}/{names[body['process']]}"
        assert channel.message_encoding == "cdr" and json.loads(channel.metadata["buffers"]) == buffers
        assert message.sequence == body["cycle"]
        by_key[(body["dpu"], body["batch_seq"], body["index"])] = (message, body)
    recs, ins = run.records, run.inputs
    assert len(recs) > 500 and len(by_key) == len(recs)
    statuses = [skelmsg.status_t.decode(bytes(d)) for _, d in log.messages(STATUS_CHANNEL)]
    offsets = {s.dpu: s.utc_ns - s.mono_ns for s in statuses}
    position = 0
    for r, rec in enumerate(recs):
        if r and (rec["dpu"], rec["batch_seq"]) != (recs[r - 1]["dpu"], recs[r - 1]["batch_seq"]):
            position = 0
        message, body = by_key[(int(rec["dpu"]), int(rec["batch_seq"]), position)]
        position += 1
        for name in RECORD_FIELDS:
            assert body[name] == int(rec[name]), (r, name)
        assert body["run_id"] == run.run_id
        assert body["release_latency_us"] == pytest.approx((rec["start_ns"] - rec["release_ns"]) / 1000)
        assert body["overrun"] == bool(rec["flags"] & skelmsg.timing_t.FLAG_OVERRUN)
        # log time: the cycle's start on the wall clock, within a few ms of the status mapping
        assert abs(message.log_time - (int(rec["start_ns"]) + offsets[int(rec["dpu"])])) < 5_000_000
        mine = ins[ins["record"] == r]
        assert len(body["inputs"]) == len(mine)
        for got, want in zip(body["inputs"], mine, strict=True):
            for name in INPUT_FIELDS:
                assert got[name] == int(want[name]), (r, name)
            assert got["transport_us"] == pytest.approx((want["recv_ns"] - want["sent_ns"]) / 1000)


def _reversed_inputs(data: bytes) -> bytes:
    """A timing batch listing its inputs last record first: the wire allows any order."""
    t = skelmsg.timing_t.decode(data)
    for name in ("in_record", "in_buffer", "in_seq", "in_new", "in_dropped", "in_received", "in_sent_ns",
                 "in_recv_ns"):  # fmt: skip
        setattr(t, name, list(getattr(t, name))[::-1])
    return t.encode()


def test_inputs_a_batch_lists_out_of_order_go_with_their_own_records(servo_run: Path, tmp_path: Path) -> None:
    events = [(e.utime_us, e.channel, _reversed_inputs(e.data) if e.channel == TIMING_CHANNEL else e.data)
              for e in read_log(servo_run / "run.lcm").iter_events()]  # fmt: skip
    shuffled = tmp_path / "run.lcm"
    shuffled.write_bytes(encode_events(events))
    export(load_run(shuffled), tmp_path / "run.mcap")

    def inputs(path: Path) -> dict[tuple[int, int, int], list[tuple[int, ...]]]:
        return {(d.dpu, d.batch_seq, d.index): sorted((i.buffer, i.seq, i.new, i.sent_ns) for i in d.inputs)
                for _, _, d in _timing(path)}  # fmt: skip

    want = inputs(servo_run / "run.mcap")
    assert sum(len(v) for v in want.values()) > 500
    assert inputs(tmp_path / "run.mcap") == want


def test_schemas_are_json_schema_or_ros2msg_and_every_message_decodes(servo_run: Path) -> None:
    with open(servo_run / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {}
        for schema in summary.schemas.values():
            if schema.name == "skeleton/msg/TimingRecord":
                assert schema.encoding == "ros2msg"
                continue
            assert schema.encoding == "jsonschema"
            body = json.loads(schema.data)
            assert body["type"] == "object" and body["$schema"].endswith("2020-12/schema")
            assert set(body["required"]) <= set(body["properties"])
            jsonschema.Draft202012Validator.check_schema(body)
            schemas[schema.id] = jsonschema.Draft202012Validator(body)
        for channel in summary.channels.values():
            assert channel.message_encoding == ("json" if channel.schema_id in schemas else "cdr")
        count = timing = 0
        for schema, _, message in reader.iter_messages():
            assert schema is not None
            if schema.id in schemas:
                schemas[schema.id].validate(json.loads(message.data))
            else:
                decoded = DecoderFactory().decoder_for("cdr", schema)(message.data)
                timing += len(decoded.inputs) >= 0
            count += 1
        records = load_records(read_log(servo_run / "run.lcm")).records
        assert count == summary.statistics.message_count and timing == len(records)
    titles = {s.schema["title"] for s in schemas.values()}
    assert {"skelmsg.status_t", "skelmsg.config_t", "skelmsg.report_t", "skelmsg.command_t"} <= titles


def test_many_chunks_are_indexed_and_read_back_in_time_order(servo_run: Path, tmp_path: Path,
                                                             monkeypatch: pytest.MonkeyPatch) -> None:
    """Small chunks: the chunk and message indexes the readers seek by are right. The log
    attached a little at a time arrives whole, and its pages are not held after it; nor
    are the MCAP's own pages once on disk (outfile.py), written in small steps here."""
    monkeypatch.setattr(mcapbulk, "CHUNK_BYTES", 8192)
    monkeypatch.setattr(mcapbulk, "ATTACH_BYTES", 100_000)
    monkeypatch.setattr(outfile, "STEP", 16 << 10)
    run = load_run(servo_run / "run.lcm")
    run.log.buf.sum()  # every page read, as by a pass over it
    counts = export(run, tmp_path / "small.mcap")
    assert mapped_kib(servo_run / "run.lcm") <= run.log.size // 1024 // 8
    size = (tmp_path / "small.mcap").stat().st_size
    assert size > 20 * outfile.STEP
    if _file_system(tmp_path) != "tmpfs":  # whose pages are the file itself
        assert _cached_bytes(tmp_path / "small.mcap") <= 3 * outfile.STEP + 4096
    assert read_as_log(tmp_path / "small.mcap").buf.tobytes() == (servo_run / "run.lcm").read_bytes()
    with open(tmp_path / "small.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None and len(summary.chunk_indexes) > 50
        times = [m.log_time for _, _, m in reader.iter_messages(log_time_order=True)]
        assert len(times) == counts["messages"] == summary.statistics.message_count
        assert times == sorted(times)
        stats = summary.statistics
        assert (times[0], times[-1]) == (stats.message_start_time, stats.message_end_time)
        topic = next(c.topic for c in summary.channels.values() if c.topic.startswith("/timing/"))
        one = [m for _, _, m in reader.iter_messages(topics=[topic])]
        assert len(one) == summary.statistics.channel_message_counts[
            next(c.id for c in summary.channels.values() if c.topic == topic)]
    with open(tmp_path / "small.mcap", "rb") as f:  # the same messages read without the indexes
        streamed = [m.log_time for _, _, m in make_reader(f).iter_messages(log_time_order=False)]
    assert sorted(streamed) == times
    assert _indexed_messages(tmp_path / "small.mcap", summary) == len(times)
    assert load_run(tmp_path / "small.mcap").report.to_json() == run.report.to_json()


def _cached_bytes(path: Path) -> int:
    """How much of the file the page cache holds (util-linux fincore)."""
    out = subprocess.run(["fincore", "--bytes", "--noheadings", "--output", "RES", str(path)],
                         capture_output=True, text=True, check=True)  # fmt: skip
    return int(out.stdout)


def _file_system(path: Path) -> str:
    return subprocess.run(["stat", "-f", "-c", "%T", str(path)], capture_output=True, text=True,
                          check=True).stdout.strip()  # fmt: skip


def _indexed_messages(path: Path, summary: Any) -> int:
    """Follows every chunk index to its chunk and every message index entry to the message
    it names (the mcap reader reads neither: Foxglove seeks by them); the entries counted."""
    data = path.read_bytes()
    entries = 0
    for chunk in summary.chunk_indexes:
        op, length = struct.unpack_from("<BQ", data, chunk.chunk_start_offset)
        assert op == 0x06 and 9 + length == chunk.chunk_length
        at = chunk.chunk_start_offset + 9 + 8 + 8 + 8 + 4
        (name,) = struct.unpack_from("<I", data, at)
        (size,) = struct.unpack_from("<Q", data, at + 4 + name)
        packed = data[at + 4 + name + 8 : at + 4 + name + 8 + size]
        assert size == chunk.compressed_size
        records = zstandard.decompress(packed, chunk.uncompressed_size) if chunk.compression else packed
        end = chunk.chunk_start_offset + chunk.chunk_length
        assert end + chunk.message_index_length <= len(data)
        for channel, offset in chunk.message_index_offsets.items():
            assert end <= offset < end + chunk.message_index_length
            op, _, on, size = struct.unpack_from("<BQHI", data, offset)
            assert (op, on) == (0x07, channel)
            previous = -1
            for k in range(size // 16):
                log_time, where = struct.unpack_from("<QQ", data, offset + 15 + 16 * k)
                op, _, on, _, at_time = struct.unpack_from("<BQHIQ", records, where)
                assert (op, on, at_time) == (0x05, channel, log_time) and log_time >= previous
                previous = log_time
                entries += 1
    return entries


def test_the_report_of_an_mcap_is_of_the_run_exported(servo_run: Path, tmp_path: Path) -> None:
    """The attached log may hold other runs: `skel report RUN.mcap` reports the exported one."""
    events = [(e.utime_us, e.channel, bytes(e.data)) for e in read_log(servo_run / "run.lcm").events]
    earlier = []
    for utime, channel, data in events:
        cls = {TIMING_CHANNEL: skelmsg.timing_t, STATUS_CHANNEL: skelmsg.status_t,
               REPORT_CHANNEL: skelmsg.report_t}.get(channel)  # fmt: skip
        if cls is not None:
            msg = cls.decode(data)
            msg.run_id -= 1000
            data = msg.encode()
        earlier.append((utime - 100_000_000, channel, data))
    two = tmp_path / "two.lcm"
    two.write_bytes(encode_events(earlier + events))
    first = load_run(two).report.run_id - 1000
    exported = skel("export", str(two), str(tmp_path / "first.mcap"), "--run-id", str(first))
    assert exported.returncode == 0, exported.stderr
    assert load_run(tmp_path / "first.mcap").report.run_id == first
    assert load_run(tmp_path / "first.mcap", first + 1000).report.run_id == first + 1000


def test_status_config_faults_attachment_and_metadata(servo_run: Path) -> None:
    log = read_log(servo_run / "run.lcm")
    topics = _messages(servo_run / "run.mcap")
    statuses = [skelmsg.status_t.decode(bytes(d)) for _, d in log.messages(STATUS_CHANNEL)]
    exported = [json.loads(m.data) for t, items in topics.items() if t.endswith("/status") for _, m in items]
    assert len(exported) == len(statuses) > 0
    assert sorted(map(json.dumps, exported)) == sorted(json.dumps(to_json(s)) for s in statuses)
    for topic in (t for t in topics if t.endswith("/status")):
        assert all(json.loads(m.data)["dpu"] == int(topic.split("/")[2]) for _, m in topics[topic])
    configs = [json.loads(m.data) for _, m in topics["/config"]]
    assert len(configs) == len(log.messages(CONFIG_CHANNEL))
    reports = [t for t in topics if t.endswith("/report")]
    assert sorted(reports) == ["/dpu/1/report", "/dpu/2/report", "/dpu/3/report", "/dpu/4/report"]
    rep = load_run(servo_run / "run.lcm").report
    faults = [json.loads(m.data) for _, m in topics.get("/faults", [])]
    # in time order in the MCAP, in kind order in the report
    assert sorted((f["kind"], f["process"] or "") for f in faults) == sorted(
        (f.kind, f.process or "") for f in rep.faults
    )
    with open(servo_run / "run.mcap", "rb") as f:
        reader = make_reader(f)
        attachments = list(reader.iter_attachments())
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
    source = (servo_run / "system.yaml").read_text()
    assert [(a.name, a.media_type) for a in attachments] == [("system.yaml", "application/yaml"),
                                                             ("run.lcm", "application/x-lcm-log")]
    assert attachments[0].data.decode() == configs[-1]["source"] and "system: servo" in source
    assert attachments[1].data == (servo_run / "run.lcm").read_bytes()
    meta = metadata["skeleton"]
    assert (meta["system"], int(meta["run_id"]), int(meta["lcm_events"])) == ("servo", rep.run_id, len(log))


def test_report_of_the_mcap_equals_report_of_the_log(servo_run: Path) -> None:
    want = load_run(servo_run / "run.lcm").report.to_json()
    assert analyze_log(read_as_log(servo_run / "run.mcap")).report.to_json() == want
    original, rebuilt = read_log(servo_run / "run.lcm"), read_as_log(servo_run / "run.mcap")
    assert [(e.channel, e.data, e.utime_us) for e in rebuilt.events] == [
        (e.channel, e.data, e.utime_us) for e in original.events
    ]


def test_skel_report_mcap_json_equals_lcm_json(servo_run: Path) -> None:
    a = skel("report", str(servo_run / "run.lcm"), "--json")
    b = skel("report", str(servo_run / "run.mcap"), "--json")
    assert a.returncode == b.returncode and a.returncode in (0, 3), b.stderr
    assert json.loads(b.stdout) == json.loads(a.stdout)


def test_damaged_events_survive_the_round_trip(servo_run: Path, tmp_path: Path) -> None:
    """Malformed messages and a repeated timing batch stay in the attached log: the report
    of the MCAP counts them as the report of the log does; the topics hold only good ones."""
    events = [(e.utime_us, e.channel, e.data) for e in read_log(servo_run / "run.lcm").events]
    timing = next(i for i, e in enumerate(events) if e[1] == TIMING_CHANNEL)
    events.insert(len(events) // 2, events[timing])  # the same batch logged twice
    events.insert(3, (events[3][0], STATUS_CHANNEL, b"not a status"))
    events.insert(5, (events[5][0], TIMING_CHANNEL, b"\x00" * 40))
    damaged = read_bytes(encode_events(events), "damaged.lcm")
    want = analyze_log(damaged).report.to_json()
    assert want["integrity"]["duplicate_batches"] == 1
    assert want["integrity"]["malformed"] == {STATUS_CHANNEL: 1, TIMING_CHANNEL: 1}
    export(analyze_log(damaged), tmp_path / "damaged.mcap")
    assert analyze_log(read_as_log(tmp_path / "damaged.mcap")).report.to_json() == want
    source = read_log(servo_run / "run.lcm")
    statuses = sum(len(v) for t, v in _messages(tmp_path / "damaged.mcap").items() if t.endswith("/status"))
    assert statuses == len(source.messages(STATUS_CHANNEL))
    assert len(_timing(tmp_path / "damaged.mcap")) == len(load_records(source).records)


def test_lcm_json_of_every_message_type_validates_against_its_schema(servo_run: Path) -> None:
    log = read_log(servo_run / "run.lcm")
    seen = set()
    for channel, cls in [(CONFIG_CHANNEL, skelmsg.config_t), (STATUS_CHANNEL, skelmsg.status_t),
                         (REPORT_CHANNEL, skelmsg.report_t), (COMMAND_CHANNEL, skelmsg.command_t),
                         (TIMING_CHANNEL, skelmsg.timing_t)]:  # fmt: skip
        validator = jsonschema.Draft202012Validator(schema_of(cls))
        for _, data in log.messages(channel):
            msg = cls.decode(bytes(data))
            body = json.loads(json.dumps(to_json(msg)))
            validator.validate(body)
            assert {k: getattr(msg, k) for k in ("dpu", "run_id") if hasattr(msg, k)} == {
                k: body[k] for k in ("dpu", "run_id") if k in body}
            seen.add(channel)
    assert len(seen) == 5
    buf = skelmsg.buffer_t()
    buf.payload, buf.nbytes = bytes(range(7)), 7
    assert to_json(buf)["payload"] == "AAECAwQFBg=="
    assert schema_of(skelmsg.buffer_t)["properties"]["payload"]["contentEncoding"] == "base64"


def _each_decoded(cls: type, messages: list[bytes]) -> list[str | None]:
    """What to_json_many must give: to_json of each message the generated decoder takes, as
    JSON (where True and 1, or 1.0 and 1, differ)."""
    out: list[str | None] = []
    for data in messages:
        try:
            msg = cls.decode(data)  # type: ignore[attr-defined]
        except Exception:
            out.append(None)
            continue
        out.append(json.dumps(to_json(msg)))
    return out


def _many(cls: type, messages: list[bytes]) -> list[str | None]:
    """to_json_many of `messages` laid end to end, as JSON, with the ranges it says it is done with."""
    lengths = np.array([len(m) for m in messages], dtype=np.int64)
    starts = np.cumsum(lengths) - lengths
    released: list[tuple[int, int]] = []
    buf = np.frombuffer(b"".join(messages) or b"\0", dtype=np.uint8)
    rows = to_json_many(cls, buf, starts, lengths, lambda a, b: released.append((a, b)))
    out = [None if r is None else json.dumps(r) for r in rows]
    assert all(a < b for a, b in released) and (not messages or released[-1][1] == int(lengths.sum()))
    return out


def test_messages_read_in_bulk_are_as_each_decoded_alone(servo_run: Path) -> None:
    """The export's bulk JSON of the control messages (lcmjson.to_json_many) is, message by
    message, to_json of the generated decoder's object, or None where that refuses it: the
    plain ones (bulk), those with array elements (one by one), strings of every kind, damaged
    ones, and every type the export writes."""
    log = read_log(servo_run / "run.lcm")
    plain = [bytes(d) for _, d in log.messages(STATUS_CHANNEL)]
    invalid = _status("abc").replace(b"abc", b"\xff\xfeA")  # not UTF-8: replaced as the decoder does
    odd = [_status(lockouts=2), _status("läb-ü"), _status(""), invalid, b"not a status", _status()[:30],
           _status()[:8] + b"\xff" * 60]
    statuses = plain + odd + plain[:3]
    rows = _many(skelmsg.status_t, statuses)
    assert rows == _each_decoded(skelmsg.status_t, statuses)
    lockouts, accented, _, replaced, refused = (json.loads(r) if r else r for r in rows[len(plain) :][:5])
    assert len(lockouts["lockouts"]) == 2 and accented["host"] == "läb-ü"
    assert replaced["host"] == "\ufffd\ufffdA" and refused is None
    for channel, (cls, _) in MESSAGE_CHANNELS.items():  # floats (report_t), nested types (config_t)
        messages = [*[bytes(d) for _, d in log.messages(channel)], b"\0" * 12]
        assert len(messages) > 1, channel
        assert _many(cls, messages) == _each_decoded(cls, messages), channel
    empty, full = skelmsg.buffer_t(), skelmsg.buffer_t()
    full.payload, full.nbytes = bytes(range(7)), 7
    buffers = [bytes(empty.encode()), bytes(full.encode())]
    assert _many(skelmsg.buffer_t, buffers) == _each_decoded(skelmsg.buffer_t, buffers)
    assert _many(skelmsg.status_t, []) == []


def test_bad_input_is_one_line_and_exit_2(tmp_path: Path, servo_run: Path) -> None:
    junk = tmp_path / "junk.lcm"
    junk.write_bytes(b"not a log" * 20)
    result = skel("export", str(junk), str(tmp_path / "x.mcap"))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    assert not (tmp_path / "x.mcap").exists()
    result = skel("export", str(servo_run / "run.mcap"), str(tmp_path / "y.mcap"))
    assert result.returncode == 2 and "already an MCAP" in result.stderr
    result = skel("export", str(servo_run / "run.lcm"), str(tmp_path / "no" / "such" / "dir.mcap"))
    assert result.returncode == 2 and len(result.stderr.strip().splitlines()) == 1
    full = skel("export", str(servo_run / "run.lcm"), str(tmp_path / "full.mcap"), file_limit=100_000)
    assert full.returncode == 2 and "File too large" in full.stderr, full.stderr
    assert len(full.stderr.strip().splitlines()) == 1
    assert not list(tmp_path.glob("full.*")), "a file written in part is left behind"
    for view in (["--trace", str(tmp_path / "full.json")], ["--parquet", str(tmp_path / "tables")]):
        full = skel("export", str(servo_run / "run.lcm"), *view, file_limit=20_000)
        assert full.returncode == 2 and "File too large" in full.stderr, full.stderr
    assert not (tmp_path / "full.json").exists() and not list(tmp_path.rglob("*.part"))
    for whole in (tmp_path / "tables").glob("*.parquet"):  # the tables written before the failure
        pq.read_table(whole)
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.finish()
    with pytest.raises(OSError, match="not an MCAP written by `skel export`"):
        read_as_log(foreign)
    with pytest.raises(OSError, match="not a readable MCAP"):
        read_as_log(junk)
    older = tmp_path / "older.mcap"
    with open(older, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.add_metadata("skeleton", {"system": "servo"})
        writer.finish()
    with pytest.raises(OSError, match=r"no run\.lcm attached: exported by an older skel, export it again"):
        read_as_log(older)
    assert np.all(np.diff([m.log_time for _, m in _messages(servo_run / "run.mcap")["/dpu/1/status"]]) >= 0)
