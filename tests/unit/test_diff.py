"""diff.py (`skel diff RUN_A RUN_B`) on two synthetic runs with known differences."""

from __future__ import annotations

import io
import json
import re
from pathlib import Path

import pytest
from analysis_synth import MS, batches, chain, report, small_config, small_run, write_log
from conftest import skel
from rich.console import Console

from skeleton.analysis.measure.run import load_run
from skeleton.analysis.views.diff import diff_command, diff_reports, diff_rows, print_diff
from skelmsg.contract import CONFIG_CHANNEL, REPORT_CHANNEL, TIMING_CHANNEL


def _run(path: Path, changed: bool) -> Path:
    """Run A: small_run. Run B: A computes 5 ms instead of 4 in the measured cycles,
    C is renamed C2, and B's system file adds a chain A -> B."""
    dpu1, dpu2 = small_run()
    config = small_config()
    if changed:
        for rec in dpu1:
            if rec.process == 0 and rec.cycle >= 2:
                rec.compute_ns = 5 * MS
        config.processes[2].name = "C2"
        config.nchains, config.chains = 1, [chain("A-B", [0, 1])]
    events: list[tuple[str, object]] = [(CONFIG_CHANNEL, config)]
    events += [(TIMING_CHANNEL, t) for t in batches(1, dpu1, 4) + batches(2, dpu2, 2)]
    events += [(REPORT_CHANNEL, report(1, 5)), (REPORT_CHANNEL, report(2, 3))]
    return write_log(path, events)


def _by(rows: list[dict], key: str) -> dict:
    return {r[key]: r for r in rows}


def test_deltas_are_exact_and_added_removed_are_marked(tmp_path: Path) -> None:
    a, b = load_run(_run(tmp_path / "a.lcm", False)).report, load_run(_run(tmp_path / "b.lcm", True)).report
    diff = diff_reports(a, b, "a.lcm", "b.lcm")
    assert diff["a"] == {"path": "a.lcm", "system": "small", "run_id": 42, "generation": 3}
    d1, d2 = diff["dpus"]
    assert (d1["id"], d1["status"], d2["status"]) == (1, "both", "both")
    # 8 measured cycles of A, 1 ms more each, over 80 ms: +10 points of compute.
    assert d1["compute_pct"]["a"] == pytest.approx(60.0) and d1["compute_pct"]["delta"] == pytest.approx(10.0)
    assert d1["overhead_pct"]["delta"] == pytest.approx(-10.0)
    assert d1["communicate_pct"]["delta"] == 0 and d1["wait_pct"]["delta"] == 0
    assert all(d2[m]["delta"] == 0 for m in ("compute_pct", "communicate_pct", "wait_pct", "overhead_pct"))
    assert d2["processes"] == {"a": ["C"], "b": ["C2"]}
    procs = _by(diff["processes"], "name")
    assert list(procs) == ["A", "B", "C", "C2"]
    assert procs["A"]["compute_mean_us"] == {"a": 4000.0, "b": 5000.0, "delta": 1000.0}
    assert procs["A"]["response_p99_us"]["delta"] == pytest.approx(1000.0)
    assert procs["A"]["overruns"] == {"a": 0, "b": 0, "delta": 0}
    assert procs["B"]["latency_p99_us"]["delta"] == 0
    assert procs["C"]["status"] == "removed" and procs["C"]["overruns"] == {"a": 1, "b": None, "delta": None}
    assert procs["C2"]["status"] == "added" and procs["C2"]["overruns"] == {"a": None, "b": 1, "delta": None}
    bufs = _by(diff["buffers"], "buffer")
    assert bufs["b_out"]["dropped"] == {"a": 3, "b": 3, "delta": 0}
    assert bufs["c_out"]["writer"] == {"a": "C", "b": "C2"}
    (ch,) = diff["chains"]
    assert (ch["name"], ch["status"], ch["samples"]["a"]) == ("A-B", "added", None)
    assert ch["samples"]["b"] == 6  # B's new cycles k = 2..9 but 4 and 7
    json.dumps(diff)


def test_diff_tables_and_cli(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    a, b = _run(tmp_path / "a.lcm", False), _run(tmp_path / "b.lcm", True)
    console = Console(file=io.StringIO(), width=120, record=True, color_system=None)
    print_diff(diff_reports(load_run(a).report, load_run(b).report, a, b), console)
    text = console.export_text()
    for title in ("per DPU: B - A", "per process: B - A", "per buffer: B - A", "per chain: B - A"):
        assert title in text
    assert "(removed)" in text and "(added)" in text and "writer C -> C2" in text
    assert re.search(r"│ A +│ overruns +│ +0 │ +0 │ +0 │", text)
    assert re.search(r"│ +│ compute mean µs +│ +4000 │ +5000 │ +\+1000 │", text)
    assert re.search(r"│ C \(removed\) +│ overruns +│ +1 │ +- │ +- │", text)
    # The real CLI: JSON with the same content, one line and exit 2 for a bad file.
    cli = skel("diff", str(a), str(b), "--json")
    assert cli.returncode == 0, cli.stderr
    want = diff_reports(load_run(a).report, load_run(b).report, a, b)
    assert json.loads(cli.stdout) == json.loads(json.dumps(want))
    same = skel("diff", str(a), str(a))
    assert same.returncode == 0 and "+" not in same.stdout.replace("+-", "").replace("-+", "")
    junk = tmp_path / "junk.lcm"
    junk.write_bytes(b"not a log" * 10)
    assert diff_command(a, junk, as_json=False) == 2
    assert capsys.readouterr().err.strip() == f"{junk}: not an LCM log (no event found)"


def test_table_delta_is_that_of_the_shown_values() -> None:
    # 90.316 and 90.314 show as 90.32 and 90.31: a Δ of 0 beside them would read as a mistake.
    row = {"id": 1, "status": "both", "compute_pct": {"a": 90.316, "b": 90.314, "delta": 90.314 - 90.316}}
    assert diff_rows([row], "id", ["compute_pct"]) == [["1", "% compute", "90.32", "90.31", "-0.01"]]
    row["compute_pct"] = {"a": 1500.2, "b": 1500.4, "delta": 0.2}  # shown without decimals: both 1500
    assert diff_rows([row], "id", ["compute_pct"])[0][2:] == ["1500", "1500", "0"]
    row["compute_pct"] = {"a": 3, "b": 5, "delta": 2}
    assert diff_rows([row], "id", ["compute_pct"])[0][2:] == ["3", "5", "+2"]
