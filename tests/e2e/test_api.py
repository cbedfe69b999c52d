"""The public Python API (`import skeleton`), the Parquet and trace exports, and one read
of the log per `skel report --plots`, on two real SERVO runs."""

from __future__ import annotations

import json
import subprocess
import sys
from collections import Counter
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
from conftest import REPO, short_servo_run, skel

import skeleton
from skeleton.analysis.measure.columns import COLUMNS
from skeleton.analysis.read import logreader, records
from skeleton.analysis.views.report import report_command
from skeleton.analysis.views.trace import PHASES


@pytest.fixture(scope="module")
def two_runs(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[Path, Path]]:
    """SERVO at two DPU speeds (the same design on faster and slower processors)."""
    base = tmp_path_factory.mktemp("api")
    outs = [base / "speed3", base / "speed2"]
    short_servo_run(outs[0], speed=3)
    short_servo_run(outs[1], speed=2)
    yield outs[0], outs[1]


def test_load_run_gives_the_report_and_tables(two_runs: tuple[Path, Path]) -> None:
    out = two_runs[0]
    run = skeleton.load_run(out)  # a run directory stands for its run.lcm
    want = json.loads((out / "report.json").read_text())
    assert run.report.to_json() == skeleton.load_run(out / "run.lcm").report.to_json()
    assert (run.report.run_id, run.report.system) == (want["run_id"], "servo")
    assert [d["id"] for d in want["dpus"]] == run.dpus.to_pandas()["id"].tolist()
    timing = run.timing.to_pandas()
    assert list(timing.columns) == list(COLUMNS["timing"])
    assert len(timing) == len(run.records) and run.timing.to_arrow().num_rows == len(timing)
    # The report's per-process latencies are the same numbers as the table's measured cycles.
    for proc in want["processes"]:
        mine = timing[(timing.process_name == proc["name"]) & timing.measured & timing.completed]
        assert len(mine) == proc["cycles"]
        assert mine.response_us.quantile(0.99) == pytest.approx(proc["response_us"]["p99"], rel=1e-9)
        assert mine.release_latency_us.quantile(0.5) == pytest.approx(proc["latency_us"]["p50"], rel=1e-9)
    receptions = run.receptions.to_pandas()
    assert list(receptions.columns) == list(COLUMNS["receptions"])
    for buf in want["buffers"]:
        mine = receptions[(receptions.buffer_name == buf["buffer"]) & receptions.new]
        assert len(mine) >= sum(r["samples"] for r in buf["readers"]) > 0
    assert list(run.faults.to_pandas().columns) == list(COLUMNS["faults"])
    assert len(run.faults) == len(want["faults"])


def test_wall_clock_is_each_dpus_own_offset(two_runs: tuple[Path, Path]) -> None:
    """to_utc_ns adds each DPU's offset (utc - mono of its heartbeats) to its times, and leaves
    a DPU with no offset known as it is: for arrays of many DPUs and for one time."""
    run = skeleton.load_run(two_runs[0])
    assert sorted(run.utc_offset_ns) == [1, 2, 3, 4]  # the four DPUs' heartbeats
    dpu = np.array([4, 1, 99, 3, 2, 1, -7], dtype=np.int16)
    mono = np.arange(len(dpu), dtype=np.int64) * 1000
    # on one host the DPUs' offsets are (nearly) one: distinct ones show each is its DPU's
    for offsets in (dict(run.utc_offset_ns), {1: 10**18, 2: -5, 3: 7, 4: -(10**17)}):
        run.utc_offset_ns = offsets
        want = mono + np.array([offsets.get(int(d), 0) for d in dpu], dtype=np.int64)
        assert run.to_utc_ns(dpu, mono).tolist() == want.tolist()
        assert int(run.to_utc_ns(3, 5)) == 5 + offsets[3] and int(run.to_utc_ns(99, 5)) == 5
        # ids no DPU can have (int16 on the wire) have no offset: not one of a DPU's by wrapping
        far = np.array([-40_000, 40_000, 2**32 + 3, 3], dtype=np.int64)
        assert run.to_utc_ns(far, np.zeros(4, np.int64)).tolist() == [0, 0, 0, offsets[3]]
        for narrow in (np.int8, np.uint16, np.int32):  # ids of any integer type
            assert run.to_utc_ns(np.array([3, 99], dtype=narrow), 5).tolist() == [5 + offsets[3], 5]


def test_compare_is_skel_diff(two_runs: tuple[Path, Path]) -> None:
    a, b = two_runs
    cli = skel("diff", str(a), str(b), "--json")
    assert cli.returncode == 0, cli.stderr
    got = skeleton.compare(skeleton.load_run(a), skeleton.load_run(b))
    assert json.loads(json.dumps(got)) == {**json.loads(cli.stdout), "a": got["a"], "b": got["b"]}
    assert {p["name"] for p in got["processes"]} >= {"jacobian_transpose", "executor"}


def test_the_api_example_runs(two_runs: tuple[Path, Path], tmp_path: Path) -> None:
    # Started elsewhere, it writes its plot beside run B, not into the directory it ran from.
    png = two_runs[1] / "response-jacobian_transpose.png"
    done = subprocess.run([sys.executable, str(REPO / "examples" / "analysis.py"), *map(str, two_runs)],
                          capture_output=True, text=True, timeout=120, check=False, cwd=tmp_path)
    assert done.returncode == 0, done.stderr
    assert png.stat().st_size > 1000 and list(tmp_path.iterdir()) == []
    png.unlink()
    p99s = []
    for out, line in zip(two_runs, done.stdout.splitlines(), strict=False):
        want = next(p for p in json.loads((out / "report.json").read_text())["processes"]
                    if p["name"] == "jacobian_transpose")
        assert line.startswith(f"{out}: jacobian_transpose response")
        p99s.append(float(line.split("p99 ")[1].split(" us")[0]))
        assert p99s[-1] == pytest.approx(want["response_us"]["p99"], abs=0.06)
    assert len(p99s) == 2


def test_parquet_tables_load_in_pandas_and_agree_with_report_json(two_runs: tuple[Path, Path],
                                                                  tmp_path: Path) -> None:
    out = two_runs[0]
    done = skel("export", str(out), "--parquet", str(tmp_path / "pq"))
    assert done.returncode == 0, done.stderr
    want = json.loads((out / "report.json").read_text())
    children = {"process_inputs": ("processes", "inputs", "name", "process"),
                "buffer_readers": ("buffers", "readers", "buffer", "buffer")}
    for name, (parent, field, key, as_name) in children.items():
        want[name] = [{as_name: row[key], **child} for row in want[parent] for child in row[field]]
    for name in ("dpus", "processes", "buffers", "chains", *children):
        table = pd.read_parquet(tmp_path / "pq" / f"{name}.parquet")
        assert len(table) == len(want[name])
        for row, expected in zip(table.to_dict("records"), want[name], strict=True):
            expected = {k: v for k, v in expected.items() if k not in ("inputs", "readers")}
            for key, value in expected.items():
                if isinstance(value, dict):
                    for sub, v in value.items():
                        if not isinstance(v, dict) and f"{key}_{sub}" in row:
                            assert _same(row[f"{key}_{sub}"], v), (name, key, sub)
                else:
                    assert _same(row[key], value), (name, key)
    timing = pd.read_parquet(tmp_path / "pq" / "timing.parquet")
    assert list(timing.columns) == list(COLUMNS["timing"])
    measured = timing[timing.measured & timing.completed]
    for proc in want["processes"]:
        mine = measured[measured.process_name == proc["name"]]
        assert mine.compute_ns.mean() / 1e3 == pytest.approx(proc["compute_mean_us"], abs=0.01)
    import pyarrow.parquet as pq

    schema = pq.read_schema(tmp_path / "pq" / "timing.parquet")
    assert schema.field("response_us").metadata[b"description"].decode() == COLUMNS["timing"]["response_us"]
    # Every per-cycle field is an int64 here, however narrow the analysis holds it.
    assert {str(schema.field(name).type) for name in records.CYCLE_FIELDS} == {"int64"}
    assert json.loads(schema.metadata[b"skeleton"])["run_id"] == want["run_id"]
    faults = pd.read_parquet(tmp_path / "pq" / "faults.parquet")
    assert sorted(faults.kind) == sorted(f["kind"] for f in want["faults"])


def _same(a: object, b: object) -> bool:
    if b is None:
        return a is None or (isinstance(a, float) and np.isnan(a))
    if isinstance(b, float):
        return bool(a == pytest.approx(b, rel=1e-9))
    if isinstance(b, list):
        return list(a) == b  # type: ignore[call-overload]
    return a == b


def test_trace_holds_one_complete_event_per_cycle_phase(two_runs: tuple[Path, Path], tmp_path: Path) -> None:
    out = two_runs[0]
    trace = tmp_path / "run.json"
    done = skel("export", str(out / "run.lcm"), "--trace", str(trace))
    assert done.returncode == 0, done.stderr
    events = json.loads(trace.read_text())["traceEvents"]
    run = skeleton.load_run(out)
    cycles = run.timing.to_pandas()
    ran = cycles[~cycles.skipped & ~cycles.release_skipped]
    complete = [e for e in events if e["ph"] == "X"]
    per_phase = Counter(e["name"] for e in complete)
    assert per_phase == {name: len(ran) for name, _ in PHASES}
    # One per (process, cycle, phase), on the process's track of its DPU, in microseconds.
    assert len({(e["tid"], e["args"]["cycle"], e["name"]) for e in complete}) == len(complete)
    first = ran.iloc[0]
    comm_in = next(e for e in complete if e["tid"] == first.process and e["args"]["cycle"] == first.cycle
                   and e["name"] == "comm in")
    host_ns = run.clock.to_host(int(first.dpu), np.array([first.start_ns]))[0]  # on one machine: start_ns
    assert comm_in["pid"] == first.dpu and comm_in["ts"] == pytest.approx(host_ns / 1e3)
    assert comm_in["dur"] == pytest.approx(first.comm_in_ns / 1e3)
    names = {e["args"]["name"] for e in events if e["ph"] == "M" and e["name"] == "thread_name"}
    assert names == set(run.process_names().values())
    overruns = [e for e in events if e["ph"] == "i" and e["cat"] == "overrun"]
    assert len(overruns) == int(ran.overrun.sum())
    faults = Counter(e["name"] for e in events if e["ph"] == "i" and e["cat"] == "fault")
    assert faults == Counter(f.kind for f in run.report.faults)


def test_report_with_plots_reads_and_decodes_the_log_once(two_runs: tuple[Path, Path], tmp_path: Path,
                                                          monkeypatch: pytest.MonkeyPatch,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    calls: Counter[str] = Counter()

    def counted(name: str, fn):  # type: ignore[no-untyped-def]
        def wrapper(*args, **kwargs):  # type: ignore[no-untyped-def]
            calls[name] += 1
            return fn(*args, **kwargs)
        return wrapper

    read_paths: list[str] = []

    def read(path: str, *args, **kwargs):  # type: ignore[no-untyped-def]
        read_paths.append(path)
        return original(path, *args, **kwargs)

    original = logreader._read
    monkeypatch.setattr(logreader, "_read", read)
    monkeypatch.setattr(records, "decode_many", counted("decode timing", records.decode_many))
    monkeypatch.setattr(records, "decode_heads", counted("decode heads", records.decode_heads))
    code = report_command(two_runs[0] / "run.lcm", as_json=True, run_id=None, plots=tmp_path / "plots")
    assert code in (0, 3)
    assert (tmp_path / "plots" / "report.html").exists()
    report = json.loads(capsys.readouterr().out)
    assert report["system"] == "servo"
    # the run's log once, and once the simulation `skel run` left beside it (RUN/simulated/)
    assert sorted(read_paths) == sorted([str(two_runs[0] / "run.lcm"),
                                         str(two_runs[0] / "simulated" / "run.lcm")])
    assert report["simulation"] is not None and report["simulation"]["dpus"]
    assert calls == {"decode timing": 2, "decode heads": 2}
