"""export_mcap.py, mcapsource.py and lcmjson.py on a real run: `skel export`, read back
with the mcap package and compared with the LCM log record by record."""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import jsonschema
import numpy as np
import pytest
from conftest import short_servo_run, skel
from mcap.reader import make_reader
from mcap.writer import Writer

import skelmsg
from skeleton.analysis.measure.run import analyze_log, load_run
from skeleton.analysis.read.lcmjson import from_json, schema_of, to_json
from skeleton.analysis.read.logreader import encode_events, read_bytes, read_log
from skeleton.analysis.read.mcapsource import read_as_log
from skeleton.analysis.read.records import load_records
from skeleton.analysis.views.export_mcap import export
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
    topics = _messages(servo_run / "run.mcap")
    by_key = {}
    for topic, items in topics.items():
        if topic.startswith("/timing/"):
            for _, message in items:
                body = json.loads(message.data)
                assert topic == f"/timing/{body['dpu']}/{names[body['process']]}"
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
        assert body["run_id"] == run.run_id and body["process_name"] == names[int(rec["process"])]
        assert body["release_latency_us"] == pytest.approx((rec["start_ns"] - rec["release_ns"]) / 1000)
        # log time: the cycle's start on the wall clock, within a few ms of the status mapping
        assert abs(message.log_time - (int(rec["start_ns"]) + offsets[int(rec["dpu"])])) < 5_000_000
        mine = ins[ins["record"] == r]
        assert len(body["inputs"]) == len(mine)
        for got, want in zip(body["inputs"], mine, strict=True):
            for name in INPUT_FIELDS:
                assert got[name] == int(want[name]), (r, name)


def test_schemas_are_json_schema_and_every_message_validates(servo_run: Path) -> None:
    with open(servo_run / "run.mcap", "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None
        schemas = {}
        for schema in summary.schemas.values():
            assert schema.encoding == "jsonschema"
            body = json.loads(schema.data)
            assert body["type"] == "object" and body["$schema"].endswith("2020-12/schema")
            assert set(body["required"]) <= set(body["properties"])
            jsonschema.Draft202012Validator.check_schema(body)
            schemas[schema.id] = jsonschema.Draft202012Validator(body)
        for channel in summary.channels.values():
            assert channel.message_encoding == "json" and channel.schema_id in schemas
        count = 0
        for schema, _, message in reader.iter_messages():
            assert schema is not None
            schemas[schema.id].validate(json.loads(message.data))
            count += 1
        assert count == summary.statistics.message_count
    titles = {s.schema["title"] for s in schemas.values()}
    assert {"skeleton.timing_record", "skelmsg.status_t", "skelmsg.config_t", "skelmsg.report_t",
            "skelmsg.command_t"} <= titles  # fmt: skip


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
    assert [(a.name, a.media_type) for a in attachments] == [("system.yaml", "application/yaml")]
    assert attachments[0].data.decode() == configs[-1]["source"] and "system: servo" in source
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
    """Malformed messages and a repeated timing batch are kept as bytes (/lcm/raw):
    the report of the MCAP counts them as the report of the log does."""
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
    raw = [json.loads(m.data)["channel"] for _, m in _messages(tmp_path / "damaged.mcap")["/lcm/raw"]]
    assert sorted(raw) == [STATUS_CHANNEL, TIMING_CHANNEL, TIMING_CHANNEL]


def test_lcm_json_round_trip_of_every_message_type(servo_run: Path) -> None:
    log = read_log(servo_run / "run.lcm")
    seen = set()
    for channel, cls in [(CONFIG_CHANNEL, skelmsg.config_t), (STATUS_CHANNEL, skelmsg.status_t),
                         (REPORT_CHANNEL, skelmsg.report_t), (COMMAND_CHANNEL, skelmsg.command_t),
                         (TIMING_CHANNEL, skelmsg.timing_t)]:  # fmt: skip
        for _, data in log.messages(channel):
            msg = cls.decode(bytes(data))
            assert from_json(cls, json.loads(json.dumps(to_json(msg)))).encode() == bytes(data)
            seen.add(channel)
    assert len(seen) == 5
    buf = skelmsg.buffer_t()
    buf.payload, buf.nbytes = bytes(range(7)), 7
    assert from_json(skelmsg.buffer_t, to_json(buf)).encode() == buf.encode()
    assert schema_of(skelmsg.buffer_t)["properties"]["payload"]["contentEncoding"] == "base64"


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
    foreign = tmp_path / "foreign.mcap"
    with open(foreign, "wb") as f:
        writer = Writer(f)
        writer.start()
        writer.finish()
    with pytest.raises(OSError, match="not an MCAP written by `skel export`"):
        read_as_log(foreign)
    with pytest.raises(OSError, match="not a readable MCAP"):
        read_as_log(junk)
    assert np.all(np.diff([m.log_time for _, m in _messages(servo_run / "run.mcap")["/dpu/1/status"]]) >= 0)
